#pragma once
// A page in a real browser: Debian's chromium, headless, renders a file:// page into a PNG and its
// log tells whether the page logged a script or console error. Without chromium on PATH a test is
// skipped, except under CI=true, where that is a failure (as for the shared test volumes).

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cctype>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "process.hpp"
#include "shared_data.hpp"

namespace lancet::test {

/// The full path of `name` on PATH, or "".
inline std::string on_path(const std::string& name) {
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path != nullptr ? path : "");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    if (dir.empty()) continue;
    const std::string candidate = dir + "/" + name;
    struct stat st {};
    if (::stat(candidate.c_str(), &st) == 0 && S_ISREG(st.st_mode) && ::access(candidate.c_str(), X_OK) == 0) return candidate;
  }
  return {};
}

/// chromium's path, or "" after recording a skip (a failure under CI=true).
inline std::string chromium_or_skip() {
  const std::string path = on_path("chromium");
  if (!path.empty()) return path;
  const std::string why = "chromium is not on PATH (Debian package chromium)";
  if (running_under_ci()) {
    [&] { FAIL() << why << ". CI=true: a CI run must have it."; }();
  } else {
    [&] { GTEST_SKIP() << why << ". Skipped (under CI=true this fails)."; }();
  }
  return {};
}

struct Render {
  bool exited = false;
  int status = -1;    // exit status when exited
  std::string log;    // chromium's stdout and stderr
};

/// Renders file://html into png (a window of width × height) with a fresh HOME (no profile of the user's is read or written).
inline Render render(const std::string& chromium, const std::filesystem::path& dir, const std::string& html, const std::string& png, int width,
                     int height) {
  const std::filesystem::path home = dir / "home";
  std::filesystem::create_directories(home);
  const std::string log_path = (dir / "chromium.log").string();
  Child child({chromium, "--headless", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--v=0",
               "--window-size=" + std::to_string(width) + "," + std::to_string(height), "--screenshot=" + png, "file://" + html},
              log_path, {"HOME=" + home.string()});
  Render r;
  if (!child.started()) return r;
  const auto st = child.wait_exit(std::chrono::seconds(120));  // on timeout the Child kills it
  r.log = read_file(log_path);
  if (st && WIFEXITED(*st)) {
    r.exited = true;
    r.status = WEXITSTATUS(*st);
  }
  return r;
}

/// The page's DOM as chromium parsed it (--dump-dom), "" when chromium did not finish.
inline std::string dump_dom(const std::string& chromium, const std::filesystem::path& dir, const std::string& html) {
  const std::filesystem::path home = dir / "home";
  std::filesystem::create_directories(home);
  const std::string out = (dir / "dom.html").string();
  Child child({chromium, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom", "file://" + html}, out, {"HOME=" + home.string()});
  if (!child.started()) return {};
  const auto st = child.wait_exit(std::chrono::seconds(120));
  return st && WIFEXITED(*st) && WEXITSTATUS(*st) == 0 ? read_file(out) : std::string();
}

/// Lines of the log that report a script error on the page.
inline std::vector<std::string> page_errors(const std::string& log) {
  std::vector<std::string> out;
  std::stringstream in(log);
  std::string line;
  while (std::getline(in, line)) {
    std::string lower = line;
    for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    const bool uncaught = lower.find("uncaught") != std::string::npos;
    const bool console_error = lower.find("error:") != std::string::npos && lower.find("console") != std::string::npos;
    if (uncaught || console_error) out.push_back(line);
  }
  return out;
}

inline std::string read_bytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

}  // namespace lancet::test
