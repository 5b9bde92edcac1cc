#include "usb_testbed.hpp"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <umockdev.h>

#include <algorithm>
#include <fstream>
#include <sstream>
#include <utility>

namespace lancet::test {
namespace {

std::string read_text(const std::string& path) {
  std::ifstream f(path);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

std::string without_sys(std::string path) { return path.rfind("/sys/", 0) == 0 ? path.substr(4) : path; }

// The paragraphs of a .umockdev file (each ends with the blank line that closes it).
std::vector<std::string> paragraphs(const std::string& text) {
  std::vector<std::string> out;
  std::size_t pos = 0;
  while (pos < text.size()) {
    std::size_t end = text.find("\n\n", pos);
    if (end == std::string::npos) end = text.size();
    out.push_back(text.substr(pos, end - pos) + "\n\n");
    pos = end + 2;
  }
  return out;
}

// A paragraph's P: path ("" when it has none).
std::string path_of(const std::string& para) {
  if (para.rfind("P: ", 0) != 0) return {};
  return para.substr(3, para.find('\n') - 3);
}

bool under(const std::string& path, const std::string& device) { return path.rfind(device + "/", 0) == 0; }

// The value after `key` on the paragraph's line that starts with it ("" when none).
std::string value_of(const std::string& para, const std::string& key) {
  for (std::size_t p = 0; p < para.size();) {
    std::size_t end = para.find('\n', p);
    if (end == std::string::npos) end = para.size();
    if (para.compare(p, key.size(), key) == 0) return para.substr(p + key.size(), end - p - key.size());
    p = end + 1;
  }
  return {};
}

// One line of the device's paragraphs at bus `bus`, address `address`.
std::string line_at_address(const std::string& line, int bus, int address) {
  char node[32];
  snprintf(node, sizeof node, "bus/usb/%03d/%03d", bus, address);
  const std::string minor = std::to_string((bus - 1) * 128 + address - 1);  // Linux's usb_device minor
  const auto starts = [&](const char* key) { return line.rfind(key, 0) == 0; };
  if (starts("N: bus/usb/")) {
    const std::size_t eq = line.find('=');
    return std::string("N: ") + node + (eq == std::string::npos ? "" : line.substr(eq));
  }
  if (starts("E: DEVNAME=/dev/bus/usb/")) return std::string("E: DEVNAME=/dev/") + node;
  if (starts("E: DEVNUM=")) return std::string("E: DEVNUM=") + std::string(node).substr(12);
  if (starts("E: MINOR=")) return "E: MINOR=" + minor;
  if (starts("A: devnum=")) return "A: devnum=" + std::to_string(address) + "\\n";
  if (starts("A: dev=189:")) return "A: dev=189:" + minor + "\\n";
  return line;
}

gboolean on_ioctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, gpointer device) {
  return static_cast<UsbdevfsDevice*>(device)->handle_ioctl(client) ? TRUE : FALSE;
}

}  // namespace

bool in_umockdev() {
  const char* p = getenv("LD_PRELOAD");
  return p != nullptr && strstr(p, "libumockdev-preload") != nullptr;
}

const char* not_in_umockdev_reason() {
  return "not running under umockdev (LD_PRELOAD has no libumockdev-preload): install the Debian package umockdev, or run "
         "this binary as `umockdev-wrapper <test binary>`";
}

void reexec_under_umockdev_if_needed(char** argv) {
  if (in_umockdev() || getenv("LANCET_UMOCKDEV_REEXEC") != nullptr) return;
  char self[4096];
  const ssize_t n = readlink("/proc/self/exe", self, sizeof self - 1);
  if (n <= 0) return;
  self[n] = '\0';
  setenv("LANCET_UMOCKDEV_REEXEC", "1", 1);  // once: never loop if the wrapper does not preload
#if defined(__SANITIZE_ADDRESS__)
  // The preload library comes before the ASan runtime in the library list: allow it.
  std::string asan = getenv("ASAN_OPTIONS") != nullptr ? getenv("ASAN_OPTIONS") : "";
  asan += std::string(asan.empty() ? "" : ":") + "verify_asan_link_order=0";
  setenv("ASAN_OPTIONS", asan.c_str(), 1);
#endif
  static char wrapper[] = "umockdev-wrapper";
  std::vector<char*> args{wrapper, self};
  for (char** a = argv + 1; *a != nullptr; ++a) args.push_back(*a);
  args.push_back(nullptr);
  execvp(wrapper, args.data());
  const char* slash = strrchr(argv[0], '/');
  fprintf(stderr, "%s: cannot run umockdev-wrapper (%s): the tests that need umockdev are skipped\n",
          slash != nullptr ? slash + 1 : argv[0], strerror(errno));
}

std::string umockdev_at_address(const std::string& umockdev_text, const std::string& sys_path, int address, bool with_others) {
  const std::string device = without_sys(sys_path);
  int bus = 1;
  for (const std::string& para : paragraphs(umockdev_text))
    if (path_of(para) == device && !value_of(para, "E: BUSNUM=").empty()) bus = std::stoi(value_of(para, "E: BUSNUM="));
  std::string out;
  for (const std::string& para : paragraphs(umockdev_text)) {
    const std::string path = path_of(para);
    const bool ours = path == device || under(path, device);
    if (!ours) {
      if (with_others) out += para;
      continue;
    }
    for (std::size_t p = 0; p < para.size();) {
      const std::size_t end = para.find('\n', p);
      out += line_at_address(para.substr(p, end - p), bus, address) + "\n";
      p = end + 1;
    }
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// UsbTestbed

UsbTestbed::UsbTestbed(UsbdevfsDevice& device, const std::string& umockdev_file, std::string sys_path)
    : device_(device), text_(read_text(umockdev_file)), sys_path_(without_sys(std::move(sys_path))) {
  EXPECT_FALSE(text_.empty()) << "cannot read " << umockdev_file;
  bool found = false;
  for (const std::string& para : paragraphs(text_)) {
    const std::string path = path_of(para);
    found = found || path == sys_path_;
    if (under(path, sys_path_)) children_.push_back(path);
    if (path == sys_path_ && !value_of(para, "E: BUSNUM=").empty()) bus_ = std::stoi(value_of(para, "E: BUSNUM="));
  }
  EXPECT_TRUE(found || text_.empty()) << umockdev_file << " has no device at " << sys_path_;
  // Deepest first: removing a device before its children would leave their /sys/bus links behind.
  std::sort(children_.begin(), children_.end(), [](const std::string& a, const std::string& b) { return a.size() > b.size(); });
  if (bus_ == 0) bus_ = 1;
  tb_ = umockdev_testbed_new();
  handler_ = umockdev_ioctl_base_new();
  g_signal_connect_data(handler_, "handle-ioctl", reinterpret_cast<GCallback>(&on_ioctl), &device_, nullptr, GConnectFlags{});
}

UsbTestbed::~UsbTestbed() {
  g_signal_handlers_disconnect_matched(handler_, G_SIGNAL_MATCH_DATA, 0, 0, nullptr, nullptr, &device_);
  g_object_unref(tb_);
  g_object_unref(handler_);
}

bool UsbTestbed::plug(int address) {
  address_ = address;
  const std::string node = devnode();
  GError* err = nullptr;
  if (std::find(attached_.begin(), attached_.end(), node) == attached_.end()) {
    if (!umockdev_testbed_attach_ioctl(tb_, node.c_str(), handler_, &err)) {
      ADD_FAILURE() << "umockdev cannot attach the device to " << node << ": " << (err != nullptr ? err->message : "");
      g_clear_error(&err);
      return false;
    }
    attached_.push_back(node);
  }
  device_.plugged_at(node);
  const std::string text = umockdev_at_address(text_, sys_path_, address, !others_added_);
  if (!umockdev_testbed_add_from_string(tb_, text.c_str(), &err)) {
    ADD_FAILURE() << "umockdev refuses the device at " << node << ": " << (err != nullptr ? err->message : "");
    g_clear_error(&err);
    return false;
  }
  others_added_ = true;
  return true;
}

void UsbTestbed::unplug() {
  device_.unplug();
  remove_from_testbed();
}

void UsbTestbed::remove_from_testbed() {
  for (const std::string& child : children_) umockdev_testbed_remove_device(tb_, ("/sys" + child).c_str());
  umockdev_testbed_remove_device(tb_, ("/sys" + sys_path_).c_str());
}

std::string UsbTestbed::devnode() const {
  char node[32];
  snprintf(node, sizeof node, "/dev/bus/usb/%03d/%03d", bus_, address_);
  return node;
}

}  // namespace lancet::test
