#pragma once
// A throwaway PostgreSQL server for tests: initdb into a temporary folder, pg_ctl start listening
// only on a Unix socket in that folder (no TCP port, nothing shared with other tests or a system
// server), stopped and removed by the destructor. Debian's postgresql package provides the
// programs (/usr/lib/postgresql/<version>/bin). PostgreSQL refuses to run as root: as root the
// server runs as the `postgres` user (runuser), which owns the folder.
//
// Tests call postgres_server() (one server per test process, started on first use) and skip
// when it is unavailable, unless CI=true, where they fail: scripts/setup.sh installs it.

#include <pwd.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>

namespace lancet::test {

class PostgresServer {
 public:
  /// Starts a server; error() says why when it did not. `durable`: fsync on, as a real server
  /// (tests run with it off: their data need not survive a power cut).
  explicit PostgresServer(bool durable = false) {
    const std::string bin = find_bin();
    if (bin.empty()) {
      error_ = "PostgreSQL is not installed (no /usr/lib/postgresql/*/bin/initdb; Debian package postgresql)";
      return;
    }
    char tmpl[] = "/tmp/lancet-pg-XXXXXX";
    if (mkdtemp(tmpl) == nullptr) {
      error_ = "cannot create a temporary folder";
      return;
    }
    dir_ = tmpl;
    std::string as_user;
    if (geteuid() == 0) {
      const passwd* pw = getpwnam("postgres");
      if (pw == nullptr) {
        error_ = "running as root and there is no postgres user to run the server as";
        return;
      }
      if (chown(dir_.c_str(), pw->pw_uid, pw->pw_gid) != 0) {
        error_ = "cannot give " + dir_ + " to the postgres user";
        return;
      }
      as_user = "runuser -u postgres -- ";
    }
    const std::string data = dir_ + "/data";
    const std::string init = as_user + bin + "/initdb -D " + data + " -U lancet --auth=trust -E UTF8 --no-sync > " + dir_ + "/initdb.log 2>&1";
    if (std::system(init.c_str()) != 0) {
      error_ = "initdb failed (" + dir_ + "/initdb.log)";
      return;
    }
    pg_ctl_ = as_user + bin + "/pg_ctl -D " + data;
    start_ = pg_ctl_ + " -w -t 60 -l " + dir_ + "/server.log -o \"-k " + dir_ + " -c listen_addresses=''" +
             (durable ? "" : " -c fsync=off") + "\" start > /dev/null 2>&1";
    if (!start()) error_ = "pg_ctl start failed (" + dir_ + "/server.log)";
  }
  ~PostgresServer() {
    if (running_) (void)std::system((pg_ctl_ + " -w -m immediate stop > /dev/null 2>&1").c_str());
    std::error_code ec;
    if (!dir_.empty() && error_.empty()) std::filesystem::remove_all(dir_, ec);
  }
  PostgresServer(const PostgresServer&) = delete;
  PostgresServer& operator=(const PostgresServer&) = delete;

  [[nodiscard]] bool running() const { return running_; }
  /// Stops the server (fast shutdown: the connections are ended), as a lab's server going away;
  /// start() brings it back with its data, at the same URL. True when done.
  bool stop() {
    if (!running_ || std::system((pg_ctl_ + " -w -m fast stop > /dev/null 2>&1").c_str()) != 0) return false;
    running_ = false;
    return true;
  }
  bool start() {
    if (!running_ && !start_.empty() && std::system(start_.c_str()) == 0) running_ = true;
    return running_;
  }
  [[nodiscard]] const std::string& error() const { return error_; }
  /// The URL of database `db` on this server (the database "postgres" always exists).
  [[nodiscard]] std::string url(const std::string& db = "postgres") const { return "postgresql://lancet@/" + db + "?host=" + dir_; }

 private:
  static std::string find_bin() {
    std::error_code ec;
    std::string best;
    for (const auto& e : std::filesystem::directory_iterator("/usr/lib/postgresql", ec)) {
      if (std::filesystem::exists(e.path() / "bin/initdb") && e.path().string() > best) best = e.path().string();
    }
    return best.empty() ? best : best + "/bin";
  }

  std::string dir_;
  std::string pg_ctl_;
  std::string start_;  ///< the pg_ctl start command
  std::string error_;
  bool running_ = false;
};

/// This process's server, started on first use and stopped at exit.
inline PostgresServer& postgres_server() {
  static PostgresServer server;
  return server;
}

/// True under CI=true: a test that needs PostgreSQL fails instead of skipping.
inline bool ci() {
  const char* ci = std::getenv("CI");
  return ci != nullptr && std::string(ci) == "true";
}

}  // namespace lancet::test
