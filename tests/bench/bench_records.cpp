// lancet-bench-records: what storing scored attempts costs on each back end of the training
// records (host_viz/records), against scoring them. Prints one JSON object on stdout.
//
//   lancet-bench-records [--attempts N] [--quick]
//
// - score: records::score_attempt on a 60 s synthetic recording of skin-incision (read the HDF5
//   file, SHA-256 it, score::compute_metrics): ms per attempt (best of 5). The yardstick.
// - store: N attempts (default 1,000; distinct content hashes, the scored attempt's metrics) each
//   stored by Store::add_attempt in its own transaction, into a fresh SQLite file (WAL,
//   synchronous=NORMAL) and into a PostgreSQL server this bench starts (initdb in /tmp, Unix
//   socket; fsync off, as the tests' server, and again on a second server with fsync on, as a
//   lab's would run: every commit waits for its WAL flush); attempts/s and ms per attempt, and the
//   ratio of a stored attempt to a scored one. Then the whole export's read (Store::attempts with
//   metrics).
// - progress_page: `progress TRAINEE -o page.html` for a trainee with --page-attempts N (default
//   500) attempts, on each back end: ms (best of 3) and its ratio to scoring one attempt
//   (records_page_bench.hpp).
// PostgreSQL is left out (with the reason in the JSON) when it cannot be started.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>

#include <unistd.h>

#include "postgres_server.hpp"  // tests/support
#include "recording/hdf5_io.hpp"
#include "records/attempt_scoring.hpp"
#include "records/store.hpp"
#include "records_page_bench.hpp"
#include "../host_viz/score/synthetic_recording.hpp"

namespace {

using namespace lancet;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

std::string read_text(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  std::string s;
  if (f == nullptr) return s;
  char buf[4096];
  for (std::size_t n = 0; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) s.append(buf, n);
  std::fclose(f);
  return s;
}

// A 60 s recording of skin-incision: walk in, cut along the line, lift off.
std::string write_session(const std::string& dir) {
  record::Recording r = record::test::make_recording(60'000, [](std::size_t i, double t, ToolSample& s) {
    s.stage = i < 5'000 || i > 55'000 ? Stage::kFree : Stage::kCutting;
    s.tool.position = Vec3{-0.015 + 0.03 * t / 60.0, -0.012 + 0.0005 * std::sin(t), 0};
    s.force = Vec3{0, 0, 0.8 + 0.2 * std::sin(3 * t)};
  });
  record::test::mark_cut_progress(r);
  const std::string scenario = std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml";
  r.scenario_toml = read_text(scenario);
  r.scenario_file = scenario;
  r.scenario_name = "skin-incision";
  const std::string path = dir + "/session.h5";
  if (auto w = record::write_recording(path, r); !w.ok()) {
    std::fprintf(stderr, "lancet-bench-records: %s\n", w.error().message.c_str());
    std::exit(1);
  }
  return path;
}

// Stores `n` copies of `a` (each its own content hash) one transaction each; prints the JSON
// fields of the run. `score_ms` is the yardstick.
void bench_store(const char* label, const std::string& db, const records::Attempt& a, int n, double score_ms, bool last) {
  auto s = records::Store::open(db);
  if (!s.ok()) {
    std::printf("  \"%s\": {\"error\": \"%s\"}%s\n", label, s.error().message.c_str(), last ? "" : ",");
    return;
  }
  records::Attempt x = a;
  const auto t0 = Clock::now();
  for (int i = 0; i < n; ++i) {
    x.content_hash = a.content_hash.substr(0, 56) + std::to_string(10'000'000 + i);
    if (auto r = s.value()->add_attempt(x); !r.ok() || !r.value()) {
      std::fprintf(stderr, "lancet-bench-records: %s\n", r.ok() ? "stored twice?" : r.error().message.c_str());
      std::exit(1);
    }
  }
  const double store_s = seconds_since(t0);
  const auto t1 = Clock::now();
  auto all = s.value()->attempts();
  const double read_s = seconds_since(t1);
  const double ms = store_s * 1e3 / n;
  std::printf("  \"%s\": {\"attempts\": %d, \"store_s\": %.3f, \"attempts_per_s\": %.1f, \"store_ms_per_attempt\": %.3f, "
              "\"store_to_score_ratio\": %.4f, \"read_all_s\": %.3f, \"read_rows\": %zu}%s\n",
              label, n, store_s, n / store_s, ms, ms / score_ms, read_s, all.ok() ? all.value().size() : std::size_t{0}, last ? "" : ",");
}

}  // namespace

int main(int argc, char** argv) {
  int n = 1000;
  int page_n = 500;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0) n = 100;
    if (std::strcmp(argv[i], "--attempts") == 0 && i + 1 < argc) n = std::max(1, std::atoi(argv[++i]));
    if (std::strcmp(argv[i], "--page-attempts") == 0 && i + 1 < argc) page_n = std::max(1, std::atoi(argv[++i]));
  }
  char tmpl[] = "/tmp/lancet-bench-records-XXXXXX";
  if (mkdtemp(tmpl) == nullptr) return 1;
  const std::string dir = tmpl;
  const std::string session = write_session(dir);

  // The yardstick: scoring one attempt (best of 5).
  double score_ms = 1e30;
  records::Attempt attempt;
  for (int rep = 0; rep < 5; ++rep) {
    const auto t0 = Clock::now();
    auto a = records::score_attempt(session, "", records::Curriculum{});
    score_ms = std::min(score_ms, seconds_since(t0) * 1e3);
    if (!a.ok()) {
      std::fprintf(stderr, "lancet-bench-records: %s\n", a.error().message.c_str());
      return 1;
    }
    attempt = std::move(a.value());
  }

  std::printf("{\n  \"bench\": \"records\",\n  \"metrics_per_attempt\": %zu,\n  \"score_ms_per_attempt\": %.3f,\n", attempt.metrics.size(), score_ms);
  lancet::test::PostgresServer& pg = lancet::test::postgres_server();
  bench_store("sqlite", dir + "/records.db", attempt, n, score_ms, false);
  if (pg.running()) {
    bench_store("postgresql", pg.url(), attempt, n, score_ms, false);
  } else {
    std::printf("  \"postgresql\": {\"error\": \"%s\"},\n", pg.error().c_str());
  }
  lancet::test::PostgresServer durable(true);
  if (durable.running()) {
    bench_store("postgresql_fsync", durable.url(), attempt, n, score_ms, false);
  } else {
    std::printf("  \"postgresql_fsync\": {\"error\": \"%s\"},\n", durable.error().c_str());
  }
  lancet::bench::bench_progress_page("progress_page_sqlite", dir + "/pages.db", attempt, page_n, score_ms, !pg.running());
  if (pg.running()) {  // a fresh database for the one trainee
    auto admin = records::sql::open_postgresql(pg.url());
    if (admin.ok() && admin.value()->execute("CREATE DATABASE bench_pages").ok()) {
      lancet::bench::bench_progress_page("progress_page_postgresql", pg.url("bench_pages"), attempt, page_n, score_ms, true);
    } else {
      std::printf("  \"progress_page_postgresql\": {\"error\": \"cannot create the database bench_pages\"}\n");
    }
  }
  std::printf("}\n");
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);
  return 0;
}
