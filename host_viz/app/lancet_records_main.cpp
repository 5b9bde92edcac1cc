// lancet-records: the training records (host_viz/records): trainees, the curriculum, and every
// recorded attempt scored and stored, in one SQLite file or a PostgreSQL server.
//   lancet-records [--db FILE|postgresql://...] import FILE.h5... [--trainee ID]
//   lancet-records trainee add ID --name NAME [--cohort C] | trainee list
//   lancet-records curriculum load FILE.toml | curriculum show
//   lancet-records progress TRAINEE [-o page.html [--reports]]
//   lancet-records cohort COHORT [-o page.html] [--stuck-after N]
//   lancet-records export --csv [-o FILE]
//   lancet-records deliver [--outbox DIR]
// --db defaults to ~/.local/share/lancet/records.db (records::default_database_path), created with
// its folders. docs/RECORDS.md is the guide.
// Exit status: 0 done; 2 bad arguments or bad input (a recording that cannot be read or scored, an
// unknown trainee or scenario, a curriculum that does not load, a database that cannot be opened
// or has a newer schema), each named on stderr. Each attempt is one transaction: an error leaves
// nothing of it behind, and an import that fails part-way keeps the attempts stored before it.

#include <CLI/CLI.hpp>

#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <memory>
#include <new>
#include <optional>
#include <string>
#include <vector>

#include "app/tool_main.hpp"
#include "records/attempt_scoring.hpp"
#include "records/cohort_page.hpp"
#include "records/curriculum.hpp"
#include "records/outbox.hpp"
#include "records/progress.hpp"
#include "records/progress_page.hpp"
#include "records/store.hpp"

namespace {

using namespace lancet;
using namespace lancet::records;

int fail(std::string message) {
  while (!message.empty() && message.back() == '\n') message.pop_back();
  std::fprintf(stderr, "lancet-records: %s\n", message.c_str());
  return 2;
}

struct Args {
  std::string db;
  std::string outbox;  ///< deliver --outbox ("" the default beside --db)
  std::vector<std::string> files;
  std::string trainee;  ///< import --trainee, progress TRAINEE
  Trainee new_trainee;
  std::string curriculum_file;
  std::string output;  ///< export, progress and cohort -o
  std::string cohort;  ///< cohort COHORT
  std::size_t stuck_after = kDefaultStuckAfter;
  bool csv = false;
  bool reports = false;  ///< progress --reports
};

int import_files(Store& store, const Args& a) {
  if (!a.trainee.empty()) {
    auto t = store.find_trainee(a.trainee);
    if (!t.ok()) return fail(t.error().message);
    if (!t.value()) return fail(store.name() + ": trainee \"" + a.trainee + "\" does not exist (add it: lancet-records trainee add " + a.trainee + " --name NAME)");
  }
  auto curriculum = store.curriculum();
  if (!curriculum.ok()) return fail(curriculum.error().message);
  int status = 0;
  for (const std::string& file : a.files) {
    auto attempt = score_attempt(file, a.trainee, curriculum.value());
    if (!attempt.ok()) {
      status = fail(attempt.error().message);
      continue;
    }
    attempt.value().scored_by = LANCET_VERSION;
    auto stored = store.add_attempt(attempt.value());
    if (!stored.ok()) {
      status = fail(file + ": " + stored.error().message);
      continue;
    }
    const Attempt& x = attempt.value();
    std::printf("%s: %s, %s (%lld of %lld banded metrics pass)%s\n", file.c_str(), x.scenario.c_str(), x.verdict.c_str(),
                static_cast<long long>(x.passed), static_cast<long long>(x.banded), stored.value() ? "" : ", already stored");
  }
  return status;
}

int list_trainees(Store& store) {
  auto ts = store.trainees();
  if (!ts.ok()) return fail(ts.error().message);
  for (const Trainee& t : ts.value()) std::printf("%s\t%s\t%s\n", t.id.c_str(), t.name.c_str(), t.cohort.c_str());
  return 0;
}

int show_curriculum(Store& store) {
  auto c = store.curriculum();
  if (!c.ok()) return fail(c.error().message);
  if (c.value().steps.empty()) return fail(store.name() + ": no curriculum loaded (lancet-records curriculum load FILE.toml)");
  std::printf("%s\n", c.value().name.c_str());
  for (std::size_t i = 0; i < c.value().steps.size(); ++i) {
    const CurriculumStep& s = c.value().steps[i];
    std::printf("  %zu. %s: proficient on %lld attempts, %lld of them in a row (scenario sha256 %s)\n", i + 1, s.scenario.c_str(),
                static_cast<long long>(s.required), static_cast<long long>(s.consecutive), s.scenario_hash.c_str());
  }
  return 0;
}

// Writes `text` to `path`; true when it was written.
bool write_file(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (out) out.write(text.data(), static_cast<std::streamsize>(text.size()));
  if (out) out.close();
  return static_cast<bool>(out);
}

// The folder `path` will be in, absolute (recording links on a page are made relative to it).
std::string page_folder(const std::string& path) {
  std::error_code ec;
  const std::filesystem::path p = std::filesystem::absolute(path, ec);
  return ec ? std::string() : p.parent_path().string();
}

// lancet-report's page for each attempt, in PAGE's folder under "<page stem>-reports/<n>.html"
// (n: the attempt's row on the page); the links relative to the page, "" where the recording could
// not be read (said on stderr). Empty when the folder cannot be made.
std::vector<std::string> write_reports(const std::vector<Attempt>& attempts, const std::string& page) {
  const std::filesystem::path page_path(page);
  const std::string folder = page_path.stem().string() + "-reports";
  std::error_code ec;
  std::filesystem::create_directories(page_path.parent_path() / folder, ec);
  if (ec) {
    std::fprintf(stderr, "lancet-records: %s: cannot make the reports' folder: %s\n", (page_path.parent_path() / folder).c_str(), ec.message().c_str());
    return {};
  }
  std::vector<std::string> links(attempts.size());
  for (std::size_t i = 0; i < attempts.size(); ++i) {
    const std::string name = folder + "/" + std::to_string(i + 1) + ".html";
    auto html = attempt_report_html(attempts[i].recording, std::filesystem::path(attempts[i].recording).filename().string());
    if (!html.ok()) {
      std::fprintf(stderr, "lancet-records: attempt %zu: no report: %s\n", i + 1, html.error().message.c_str());
      continue;
    }
    if (write_file((page_path.parent_path() / name).string(), html.value())) links[i] = name;
  }
  return links;
}

int show_progress(Store& store, const std::string& id, const std::string& output, bool reports) {
  auto t = store.find_trainee(id);
  if (!t.ok()) return fail(t.error().message);
  if (!t.value()) return fail(store.name() + ": trainee \"" + id + "\" does not exist");
  auto c = store.curriculum();
  if (!c.ok()) return fail(c.error().message);
  if (c.value().steps.empty()) return fail(store.name() + ": no curriculum loaded (lancet-records curriculum load FILE.toml)");
  auto attempts = store.attempts(AttemptFilter{id, std::nullopt, !output.empty()});
  if (!attempts.ok()) return fail(attempts.error().message);
  const Progress p = progress(*t.value(), c.value(), attempts.value());
  if (output.empty()) {
    const std::string text = progress_text(p);
    std::fwrite(text.data(), 1, text.size(), stdout);
    return 0;
  }
  ProgressPageOptions options{{}, page_folder(output), {}};
  if (reports) options.reports = write_reports(attempts.value(), output);
  if (!write_file(output, progress_html(p, attempts.value(), options))) return fail(output + ": cannot write the page");
  return 0;
}

int show_cohort(Store& store, const Args& a) {
  auto all = store.trainees();
  if (!all.ok()) return fail(all.error().message);
  std::vector<Trainee> members;
  for (const Trainee& t : all.value()) {
    if (t.cohort == a.cohort) members.push_back(t);
  }
  if (members.empty()) return fail(store.name() + ": cohort \"" + a.cohort + "\" has no trainees (lancet-records trainee add ID --name NAME --cohort " + a.cohort + ")");
  auto c = store.curriculum();
  if (!c.ok()) return fail(c.error().message);
  if (c.value().steps.empty()) return fail(store.name() + ": no curriculum loaded (lancet-records curriculum load FILE.toml)");
  auto attempts = store.attempts(AttemptFilter{std::nullopt, a.cohort, false});
  if (!attempts.ok()) return fail(attempts.error().message);
  const Cohort k = cohort(a.cohort, members, c.value(), attempts.value(), a.stuck_after);
  if (a.output.empty()) {
    const std::string text = cohort_text(k);
    std::fwrite(text.data(), 1, text.size(), stdout);
    return 0;
  }
  if (!write_file(a.output, cohort_html(k))) return fail(a.output + ": cannot write the page");
  return 0;
}

int export_records(Store& store, const Args& a) {
  auto attempts = store.attempts();
  if (!attempts.ok()) return fail(attempts.error().message);
  auto trainees = store.trainees();
  if (!trainees.ok()) return fail(trainees.error().message);
  const std::string csv = export_csv(attempts.value(), trainees.value());
  if (a.output.empty() || a.output == "-") {
    std::fwrite(csv.data(), 1, csv.size(), stdout);
    return 0;
  }
  std::ofstream out(a.output, std::ios::binary | std::ios::trunc);
  if (out) out.write(csv.data(), static_cast<std::streamsize>(csv.size()));
  if (out) out.close();
  if (!out) return fail(a.output + ": cannot write the export");
  return 0;
}

// A station's outbox into the records: exit 0 when it is empty afterwards, 2 when attempts still
// wait (the database cannot be reached) or some were moved aside (each named).
int deliver_outbox(const Args& a) {
  Outbox box(a.outbox.empty() ? default_outbox_path(a.db) : a.outbox);
  const Delivery d = box.deliver(a.db, LANCET_VERSION);
  for (const std::string& r : d.rejected) (void)fail(r + " (moved aside, not tried again)");
  std::printf("%s: %zu attempts stored, %zu stored before, %zu waiting\n", box.dir().c_str(), d.stored, d.already_stored, d.waiting);
  if (d.waiting > 0) return fail("attempts still wait in " + box.dir() + ": " + d.error);
  return d.rejected.empty() ? 0 : 2;
}

int run(int argc, char** argv) {
  CLI::App app{"lancet-records: trainees, the curriculum and every scored attempt, in SQLite or PostgreSQL"};
  app.require_subcommand(1);
  Args a;
  a.db = default_database_path();
  app.add_option("--db", a.db, "an SQLite file (created with its folders) or a postgresql:// URL")->capture_default_str();
  auto* import_cmd = app.add_subcommand("import", "score recordings (.h5) and store them as attempts (one already stored is skipped)");
  import_cmd->add_option("files", a.files, "recordings written by lancet-viz")->required();
  import_cmd->add_option("--trainee", a.trainee, "whose attempts they are (default: none)");
  auto* trainee_cmd = app.add_subcommand("trainee", "trainees")->require_subcommand(1);
  auto* trainee_add = trainee_cmd->add_subcommand("add", "add a trainee");
  trainee_add->add_option("id", a.new_trainee.id, "the trainee's id")->required();
  trainee_add->add_option("--name", a.new_trainee.name, "the trainee's name")->required();
  trainee_add->add_option("--cohort", a.new_trainee.cohort, "the trainee's cohort");
  auto* trainee_list = trainee_cmd->add_subcommand("list", "every trainee: id, name, cohort (tab-separated)");
  auto* curriculum_cmd = app.add_subcommand("curriculum", "the curriculum")->require_subcommand(1);
  auto* curriculum_load = curriculum_cmd->add_subcommand("load", "replace the curriculum with a TOML file's (docs/RECORDS.md)");
  curriculum_load->add_option("file", a.curriculum_file, "the curriculum (.toml)")->required();
  auto* curriculum_show = curriculum_cmd->add_subcommand("show", "the curriculum's steps and their rules");
  auto* progress_cmd = app.add_subcommand("progress", "a trainee's standing on each step of the curriculum and the next scenario");
  progress_cmd->add_option("trainee", a.trainee, "the trainee's id")->required();
  progress_cmd->add_option("-o,--output", a.output, "write an HTML page (learning curves, CUSUM, attempts) instead of text");
  progress_cmd->add_flag("--reports", a.reports,
                         "with -o: also write lancet-report's page for each attempt (beside the page, in <page>-reports/) and link them");
  auto* cohort_cmd = app.add_subcommand("cohort", "every trainee of a cohort: current step, attempts, last attempt, who is stuck");
  cohort_cmd->add_option("cohort", a.cohort, "the cohort")->required();
  cohort_cmd->add_option("-o,--output", a.output, "write an HTML page instead of text");
  cohort_cmd->add_option("--stuck-after", a.stuck_after, "stuck: this many attempts at the current step without meeting it")
      ->capture_default_str()->check(CLI::PositiveNumber);
  auto* export_cmd = app.add_subcommand("export", "every attempt's every metric");
  export_cmd->add_flag("--csv", a.csv, "as CSV (the only format)")->required();
  export_cmd->add_option("-o,--output", a.output, "the file to write (default: stdout)");
  auto* deliver_cmd = app.add_subcommand("deliver", "store the attempts waiting in a station's outbox (lancet-viz --trainee)");
  deliver_cmd->add_option("--outbox", a.outbox, "the outbox folder (default: beside an SQLite --db, else ~/.local/share/lancet/outbox)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : 2;
  }

  // A curriculum is read before the database is touched: a bad file changes nothing.
  std::optional<Curriculum> curriculum;
  if (*curriculum_load) {
    auto c = load_curriculum(a.curriculum_file);
    if (!c.ok()) return fail(c.error().message);
    curriculum = std::move(c.value());
  }
  if (*deliver_cmd) return deliver_outbox(a);
  auto opened = Store::open(a.db);
  if (!opened.ok()) return fail(opened.error().message);
  Store& store = *opened.value();

  if (*import_cmd) return import_files(store, a);
  if (*trainee_add) {
    if (auto r = store.add_trainee(a.new_trainee); !r.ok()) return fail(r.error().message);
    return 0;
  }
  if (*trainee_list) return list_trainees(store);
  if (curriculum) {
    if (auto r = store.set_curriculum(*curriculum); !r.ok()) return fail(r.error().message);
    std::printf("%s: curriculum \"%s\", %zu scenarios\n", store.name().c_str(), curriculum->name.c_str(), curriculum->steps.size());
    return 0;
  }
  if (*curriculum_show) return show_curriculum(store);
  if (*progress_cmd) {
    if (a.reports && a.output.empty()) return fail("progress --reports needs -o page.html: the reports are linked from the page");
    return show_progress(store, a.trainee, a.output, a.reports);
  }
  if (*cohort_cmd) return show_cohort(store, a);
  if (*export_cmd) return export_records(store, a);
  return fail("no command");
}

}  // namespace

int main(int argc, char** argv) {
  return lancet::app::guarded_main([&] { return run(argc, argv); }, [](const std::string& m) { return fail(m); });
}
