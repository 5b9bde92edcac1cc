// lancet-viz --trainee (app/station.hpp): the outbox, the delivery thread, the trainee's standing.

#include "app/station.hpp"

#include <unistd.h>

#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <mutex>
#include <optional>

#include "records/outbox.hpp"
#include "records/progress.hpp"
#include "records/store.hpp"
#include "text/text.hpp"

namespace lancet::viz {

using Lines = std::vector<std::pair<std::string, bool>>;

struct Station::Shared {
  StationOptions o;
  std::mutex m;
  std::condition_variable wake;  ///< a delivery asked for, or the end
  std::condition_variable idle;  ///< a delivery done
  bool request = false, stop = false, busy = false;
  Lines lines;                   ///< the panel's; under m
};

namespace {

Lines unreachable(std::size_t waiting, const std::string& why) {
  const std::string first = why.substr(0, why.find('\n'));
  return {{text::format("records unreachable: %zu attempt%s waiting", waiting, waiting == 1 ? "" : "s"), true}, {first, true}};
}

// Where the trainee stands, from the store; nothing when it cannot be read.
std::optional<Lines> standing(records::Store& store, const std::string& id) {
  auto t = store.find_trainee(id);
  auto c = store.curriculum();
  auto a = store.attempts(records::AttemptFilter{id, std::nullopt, false});
  if (!t.ok() || !c.ok() || !a.ok() || !t.value()) return std::nullopt;
  const records::Progress p = records::progress(*t.value(), c.value(), a.value());
  Lines lines{{text::format("trainee %s (%s): %zu attempts stored", id.c_str(), t.value()->name.c_str(), a.value().size()), false}};
  if (p.steps.empty()) {
    lines.emplace_back("no curriculum loaded", false);
  } else if (!p.next) {
    lines.emplace_back(text::format("curriculum \"%s\" done: all %zu steps proficient", p.curriculum.c_str(), p.steps.size()), false);
  } else {
    const records::StepProgress& s = p.steps[*p.next];
    // Short lines: the panel has a fixed width.
    lines.emplace_back(text::format("step %zu of %zu: %s", *p.next + 1, p.steps.size(), s.step.scenario.c_str()), false);
    lines.emplace_back(text::format("  %zu attempts, %zu proficient (needs %lld, %lld in a row)", s.standing.attempts, s.standing.passes,
                                    static_cast<long long>(s.step.required), static_cast<long long>(s.step.consecutive)),
                       false);
    lines.emplace_back("next scenario: " + s.step.scenario, false);
  }
  return lines;
}

// One delivery of what waits, then the standing (or why it cannot be had) for the panel.
Lines deliver(const StationOptions& o) {
  records::Outbox box(o.outbox);
  auto store = records::Store::open(o.db);
  if (!store.ok()) return unreachable(box.waiting().size(), store.error().message);
  const records::Delivery d = box.deliver(*store.value(), o.version);
  for (const std::string& r : d.rejected) std::fprintf(stderr, "lancet-viz: records: %s (moved aside, not tried again)\n", r.c_str());
  if (d.stored + d.already_stored > 0)
    std::fprintf(stderr, "lancet-viz: records: %zu attempts stored (%zu of them before)\n", d.stored + d.already_stored, d.already_stored);
  if (d.waiting > 0) return unreachable(d.waiting, d.error);
  auto lines = standing(*store.value(), o.trainee);
  if (!lines) return unreachable(0, store.value()->name() + ": the trainee's standing cannot be read");
  return *lines;
}

void deliveries(const std::shared_ptr<Station::Shared>& s) {
  for (;;) {
    {
      std::unique_lock l(s->m);
      s->wake.wait(l, [&] { return s->request || s->stop; });
      if (!s->request) return;  // the end, nothing more asked
      s->request = false;
      s->busy = true;
    }
    Lines lines = deliver(s->o);
    {
      std::lock_guard l(s->m);
      if (lines != s->lines) {
        for (const auto& [text, alert] : lines) std::fprintf(stderr, "lancet-viz: records: %s\n", text.c_str());
      }
      s->lines = std::move(lines);
      s->busy = false;
    }
    s->idle.notify_all();
  }
}

// The trainee at the start: an error (kNotFound) when the records say there is none; when they
// cannot be reached, a line on stderr and on we go.
Result<void> check_trainee(const StationOptions& o) {
  auto store = records::Store::open(o.db);
  std::string why;
  if (store.ok()) {
    auto t = store.value()->find_trainee(o.trainee);
    if (t.ok() && t.value()) return {};
    if (t.ok())
      return Error{ErrorCode::kNotFound, store.value()->name() + ": trainee \"" + o.trainee +
                                             "\" does not exist (add it: lancet-records trainee add " + o.trainee + " --name NAME)"};
    why = t.error().message;
  } else {
    why = store.error().message;
  }
  std::fprintf(stderr, "lancet-viz: records unreachable (%s): the attempts wait in %s and are delivered when they can be\n",
               why.substr(0, why.find('\n')).c_str(), o.outbox.c_str());
  return {};
}

}  // namespace

Result<std::unique_ptr<Station>> Station::start(StationOptions o) {
  if (o.db.empty()) o.db = records::default_database_path();
  if (o.outbox.empty()) o.outbox = records::default_outbox_path(o.db);
  // A server that does not answer holds a start or a delivery this long at most (libpq's own
  // setting wins when it is set).
  setenv("PGCONNECT_TIMEOUT", "5", 0);
  std::error_code ec;
  std::filesystem::create_directories(o.outbox, ec);
  if (ec) return Error{ErrorCode::kSystem, o.outbox + ": cannot create the outbox: " + ec.message()};
  if (auto checked = check_trainee(o); !checked.ok()) return checked.error();
  auto shared = std::make_shared<Shared>();
  shared->o = std::move(o);
  std::unique_ptr<Station> station(new Station(std::move(shared)));
  station->ask_delivery();  // what an earlier run left waiting
  return station;
}

Station::Station(std::shared_ptr<Shared> shared) : shared_(std::move(shared)) {
  thread_ = std::thread([s = shared_] { deliveries(s); });
}

Station::~Station() { finish(std::chrono::seconds(5)); }

std::string Station::recording_path() {
  char when[32];
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  std::strftime(when, sizeof when, "%Y%m%dT%H%M%SZ", &tm);
  return shared_->o.outbox + "/.recording-" + when + "-" + std::to_string(getpid()) + "-" + std::to_string(++recordings_) + ".h5";
}

bool Station::records_into_outbox(const std::string& path) const { return path.rfind(shared_->o.outbox + "/.recording-", 0) == 0; }

void Station::attempt_recorded(const std::string& path) {
  records::Outbox box(shared_->o.outbox);
  auto added = box.add(path, shared_->o.trainee, records_into_outbox(path));
  if (!added.ok()) {
    std::fprintf(stderr, "lancet-viz: records: %s: the attempt is not kept for the records\n", added.error().message.c_str());
    return;
  }
  ask_delivery();
}

void Station::ask_delivery() {
  {
    std::lock_guard l(shared_->m);
    shared_->request = true;
  }
  shared_->wake.notify_one();
}

Lines Station::panel_lines() const {
  std::lock_guard l(shared_->m);
  return shared_->lines;
}

void Station::finish(std::chrono::milliseconds wait) {
  if (finished_) return;
  finished_ = true;
  bool done = false;
  {
    std::unique_lock l(shared_->m);
    shared_->stop = true;
    shared_->wake.notify_one();
    done = shared_->idle.wait_for(l, wait, [&] { return !shared_->busy && !shared_->request; });
  }
  // A delivery still under way (a server that does not answer) ends with the process; the entry
  // it holds stays in the outbox until stored, and one stored but not yet removed is found stored
  // next time.
  if (done) {
    thread_.join();
  } else {
    thread_.detach();
  }
  const std::size_t waiting = records::Outbox(shared_->o.outbox).waiting().size();
  if (waiting > 0)
    std::fprintf(stderr, "lancet-viz: records: %zu attempt%s wait in %s (delivered at the next start, or by lancet-records deliver)\n",
                 waiting, waiting == 1 ? "" : "s", shared_->o.outbox.c_str());
}

}  // namespace lancet::viz
