#pragma once
// lancet-records run by a test, on its back end's database (test_database.hpp).

#include <sys/wait.h>

#include <chrono>
#include <string>
#include <vector>

#include "process.hpp"
#include "test_database.hpp"

namespace lancet::records::test {

/// The lancet-records this build made.
inline const std::string kRecords = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-records";

struct CliRun {
  int status = -1;  ///< exit status (-1: did not exit)
  std::string output;
};

/// A BackendTest that runs lancet-records on its database.
class CliTest : public BackendTest {
 protected:
  /// Runs lancet-records --db <db> args... and waits for it (3 minutes at most); stdout and stderr together.
  CliRun cli(const std::vector<std::string>& args) {
    std::vector<std::string> argv{kRecords, "--db", db_};
    argv.insert(argv.end(), args.begin(), args.end());
    const std::string out = dir_ + "/out" + std::to_string(++runs_) + ".txt";
    lancet::test::Child child(argv, out);
    const auto st = child.wait_exit(std::chrono::minutes(3));
    CliRun r;
    if (st && WIFEXITED(*st)) r.status = WEXITSTATUS(*st);
    r.output = lancet::test::read_file(out);
    return r;
  }

 private:
  int runs_ = 0;
};

}  // namespace lancet::records::test
