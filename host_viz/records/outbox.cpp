// A station's outbox (records/outbox.hpp): entries made whole by a rename, delivered oldest first.

#include "records/outbox.hpp"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>

#include "records/attempt_scoring.hpp"

namespace lancet::records {
namespace {

namespace fs = std::filesystem;

constexpr const char* kRecording = "recording.h5";
constexpr const char* kEntry = "entry";
constexpr const char* kRejected = ".rejected";

struct EntryMeta {
  std::string trainee;
  std::string source;
};

// A name no other entry has: when (UTC, to the second), this process, and a count within it.
std::string entry_name() {
  static std::atomic<unsigned> count{0};
  char when[32];
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  std::strftime(when, sizeof when, "%Y%m%dT%H%M%SZ", &tm);
  return std::string(when) + "-" + std::to_string(getpid()) + "-" + std::to_string(++count);
}

Result<void> write_text(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (out) out.write(text.data(), static_cast<std::streamsize>(text.size()));
  if (out) out.close();
  if (!out) return Error{ErrorCode::kSystem, path.string() + ": cannot write"};
  return {};
}

Result<EntryMeta> read_meta(const fs::path& entry) {
  std::ifstream in(entry / kEntry);
  if (!in) return Error{ErrorCode::kInvalid, (entry / kEntry).string() + ": missing"};
  EntryMeta m;
  bool has_trainee = false;
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("trainee=", 0) == 0) m.trainee = line.substr(8), has_trainee = true;
    if (line.rfind("source=", 0) == 0) m.source = line.substr(7);
  }
  if (!has_trainee) return Error{ErrorCode::kInvalid, (entry / kEntry).string() + ": no trainee= line"};
  return m;
}

// The recording into the entry being built: renamed, or linked (a second name for the same
// file: instant, and a recording is never written again), or copied where neither can cross file
// systems (then, for a move, the original removed).
Result<void> bring_in(const fs::path& from, const fs::path& to, bool move) {
  std::error_code ec;
  if (move) {
    fs::rename(from, to, ec);
    if (!ec) return {};
    if (ec != std::errc::cross_device_link) return Error{ErrorCode::kSystem, from.string() + ": cannot move into the outbox: " + ec.message()};
  } else {
    fs::create_hard_link(from, to, ec);
    if (!ec) return {};
    ec.clear();
  }
  fs::copy_file(from, to, ec);
  if (ec) return Error{ErrorCode::kSystem, from.string() + ": cannot copy into the outbox: " + ec.message()};
  if (move) fs::remove(from, ec);
  return {};
}

}  // namespace

std::string default_outbox_path(const std::string& db) {
  const bool pg = db.rfind("postgresql://", 0) == 0 || db.rfind("postgres://", 0) == 0;
  if (!db.empty() && !pg) {
    const fs::path folder = fs::path(db).parent_path();
    return (folder.empty() ? fs::path("outbox") : folder / "outbox").string();
  }
  if (const char* xdg = std::getenv("XDG_DATA_HOME"); xdg != nullptr && *xdg != '\0') return std::string(xdg) + "/lancet/outbox";
  const char* home = std::getenv("HOME");
  return std::string(home != nullptr ? home : ".") + "/.local/share/lancet/outbox";
}

Result<std::string> Outbox::add(const std::string& recording, const std::string& trainee, bool move) {
  if (trainee.find('\n') != std::string::npos) return Error{ErrorCode::kInvalid, "trainee id with a line break: \"" + trainee + "\""};
  std::error_code ec;
  if (!fs::is_regular_file(recording, ec)) return Error{ErrorCode::kNotFound, recording + ": no such recording"};
  fs::create_directories(dir_, ec);
  if (ec) return Error{ErrorCode::kSystem, dir_ + ": cannot create the outbox: " + ec.message()};
  const std::string name = entry_name();
  const fs::path building = fs::path(dir_) / (".new-" + name);
  const fs::path entry = fs::path(dir_) / name;
  fs::create_directory(building, ec);
  if (ec) return Error{ErrorCode::kSystem, building.string() + ": cannot create: " + ec.message()};
  const auto undo = [&](Error e) {
    std::error_code ignored;
    if (move && fs::exists(building / kRecording, ignored)) fs::rename(building / kRecording, recording, ignored);
    fs::remove_all(building, ignored);
    return e;
  };
  if (auto r = write_text(building / kEntry, "trainee=" + trainee + "\nsource=" + fs::absolute(recording, ec).string() + "\n"); !r.ok())
    return undo(r.error());
  if (auto r = bring_in(recording, building / kRecording, move); !r.ok()) return undo(r.error());
  // The entry appears whole: one rename.
  fs::rename(building, entry, ec);
  if (ec) return undo(Error{ErrorCode::kSystem, entry.string() + ": cannot put the entry in place: " + ec.message()});
  return entry.string();
}

std::vector<std::string> Outbox::waiting() const {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir_, ec)) {
    const std::string name = e.path().filename().string();
    if (name.empty() || name[0] == '.' || !e.is_directory(ec)) continue;
    out.push_back(e.path().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

Delivery Outbox::deliver(Store& store, const std::string& scored_by) {
  Delivery d;
  const std::vector<std::string> entries = waiting();
  if (entries.empty()) return d;
  auto curriculum = store.curriculum();
  if (!curriculum.ok()) {
    d.waiting = entries.size();
    d.error = curriculum.error().message;
    return d;
  }
  // Moves an entry that can never be stored aside, with why, once.
  const auto reject = [&](const fs::path& entry, const std::string& why) {
    std::error_code ec;
    if (!fs::exists(entry, ec)) return;  // delivered by another process meanwhile
    (void)write_text(entry / "reason", why + "\n");
    const fs::path aside = fs::path(dir_) / kRejected;
    fs::create_directories(aside, ec);
    fs::rename(entry, aside / entry.filename(), ec);
    d.rejected.push_back(entry.string() + ": " + why + (ec ? " (and it cannot be moved to " + aside.string() + ": " + ec.message() + ")" : ""));
  };
  for (std::size_t i = 0; i < entries.size(); ++i) {
    const fs::path entry = entries[i];
    const auto leave_rest = [&](const std::string& why) {
      d.waiting = entries.size() - i;
      d.error = why;
    };
    auto meta = read_meta(entry);
    if (!meta.ok()) {
      reject(entry, meta.error().message);
      continue;
    }
    const EntryMeta& m = meta.value();
    if (!m.trainee.empty()) {
      auto t = store.find_trainee(m.trainee);
      if (!t.ok()) {
        leave_rest(t.error().message);
        break;
      }
      if (!t.value()) {
        reject(entry, store.name() + ": trainee \"" + m.trainee + "\" does not exist");
        continue;
      }
    }
    auto attempt = score_attempt((entry / kRecording).string(), m.trainee, curriculum.value());
    if (!attempt.ok()) {
      reject(entry, attempt.error().message);
      continue;
    }
    attempt.value().recording = m.source.empty() ? (entry / kRecording).string() : m.source;
    attempt.value().scored_by = scored_by;
    auto added = store.add_attempt(attempt.value());
    if (!added.ok()) {
      leave_rest(added.error().message);
      break;
    }
    ++(added.value() ? d.stored : d.already_stored);
    std::error_code ec;
    fs::remove_all(entry, ec);
  }
  return d;
}

Delivery Outbox::deliver(const std::string& db, const std::string& scored_by) {
  auto store = Store::open(db);
  if (!store.ok()) {
    Delivery d;
    d.waiting = waiting().size();
    d.error = store.error().message;
    return d;
  }
  return deliver(*store.value(), scored_by);
}

}  // namespace lancet::records
