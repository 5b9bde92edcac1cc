#pragma once
// The records' tests run once per back end: a fresh SQLite file in a temporary folder, or a fresh
// database on this test process's own PostgreSQL server (tests/support/postgres_server.hpp).

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>

#include "postgres_server.hpp"
#include "records/sql.hpp"

namespace lancet::records::test {

enum class Backend { kSqlite, kPostgres };

inline std::string backend_name(const ::testing::TestParamInfo<Backend>& info) {
  return info.param == Backend::kSqlite ? "sqlite" : "postgresql";
}

/// A test with a temporary folder and a fresh database of its back end (GetParam()).
class BackendTest : public ::testing::TestWithParam<Backend> {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/lancet-records-test-XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
    if (GetParam() == Backend::kSqlite) {
      db_ = dir_ + "/records.db";
      return;
    }
    lancet::test::PostgresServer& server = lancet::test::postgres_server();
    if (!server.running()) {
      if (lancet::test::ci()) FAIL() << "CI=true and the PostgreSQL test server did not start: " << server.error();
      GTEST_SKIP() << "PostgreSQL tests skipped: " << server.error();
    }
    static int n = 0;
    const std::string name = "records_" + std::to_string(getpid()) + "_" + std::to_string(++n);
    auto admin = sql::open_postgresql(server.url());
    ASSERT_TRUE(admin.ok()) << admin.error().message;
    auto created = admin.value()->execute("CREATE DATABASE " + name);
    ASSERT_TRUE(created.ok()) << created.error().message;
    db_ = server.url(name);
  }
  void TearDown() override {
    std::error_code ec;
    if (!dir_.empty()) std::filesystem::remove_all(dir_, ec);
  }

  std::string dir_;  ///< the test's temporary folder
  std::string db_;   ///< what --db / Store::open take
};

}  // namespace lancet::records::test
