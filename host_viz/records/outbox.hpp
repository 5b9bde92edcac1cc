#pragma once
// A station's outbox: finished attempts' recordings waiting to be stored in the records. A station
// puts each attempt here first and then delivers what waits; when the database cannot be reached
// the attempts stay until a later delivery (the next one, the next start of lancet-viz, or
// `lancet-records deliver`). Nothing is stored twice: an attempt is keyed by its recording's
// content hash, so a recording stored before (a crash between storing and removing it) is just
// removed.
//
// On disk, the folder holds one entry per attempt, a folder named after when it was added:
//   DIR/20261127T034501Z-4242-1/recording.h5   the recording (moved, linked or copied in)
//   DIR/20261127T034501Z-4242-1/entry          "trainee=ID\nsource=PATH\n" (whose; where it was made)
// An entry is built in DIR/.new-* and renamed into place (atomic), so a crash never leaves a half
// entry: only whole entries are delivered, and .new-* folders are left for a person to look at.
// An entry that can never be stored (a corrupt recording, a scenario the curriculum lacks, a
// trainee that does not exist) is moved to DIR/.rejected/ with a `reason` file beside it, once,
// and never tried again. Names beginning with "." are not entries.
//
// Tools only (allocates, reads whole files, blocks on the database); one Outbox per thread.
// Several processes may deliver one outbox at once: the content hash keeps each attempt stored
// once, and an entry removed under one is skipped by the other.

#include <cstddef>
#include <string>
#include <vector>

#include "lancet/shared_model/result.hpp"
#include "records/store.hpp"

namespace lancet::records {

/// Where a station's outbox is when none is given: beside an SQLite --db file
/// (FILE's folder/outbox), else $XDG_DATA_HOME/lancet/outbox or ~/.local/share/lancet/outbox.
[[nodiscard]] std::string default_outbox_path(const std::string& db);

/// What one delivery did.
struct Delivery {
  std::size_t stored = 0;          ///< attempts stored now
  std::size_t already_stored = 0;  ///< were stored before: removed from the outbox
  std::size_t waiting = 0;         ///< left in the outbox (the database failed or is unreachable)
  std::vector<std::string> rejected;  ///< one line per entry moved to .rejected/: the entry and why
  std::string error;               ///< why entries were left waiting ("" none)
};

class Outbox {
 public:
  /// The outbox at `dir` (created with its folders on first add).
  explicit Outbox(std::string dir) : dir_(std::move(dir)) {}

  [[nodiscard]] const std::string& dir() const noexcept { return dir_; }

  /// Puts the recording at `recording` into the outbox as `trainee`'s attempt: moved when `move`,
  /// else linked (a second name for the file; copied when on another file system). Returns the entry's folder. The entry
  /// appears whole or not at all; on error (naming the file) the recording is where it was.
  [[nodiscard]] Result<std::string> add(const std::string& recording, const std::string& trainee, bool move);

  /// The entries waiting, oldest first (their folders).
  [[nodiscard]] std::vector<std::string> waiting() const;

  /// Scores and stores every waiting entry into `store`, oldest first; `scored_by` is the
  /// version stored with each attempt. An entry stored (or found stored) is removed; one that can
  /// never be stored is moved to .rejected/; when storing fails otherwise (the database went
  /// away), that entry and the rest stay for the next delivery.
  [[nodiscard]] Delivery deliver(Store& store, const std::string& scored_by);

  /// Delivers into the database `db` (Store::open): when it cannot be opened every entry stays,
  /// and the Delivery's error says why.
  [[nodiscard]] Delivery deliver(const std::string& db, const std::string& scored_by);

 private:
  std::string dir_;
};

}  // namespace lancet::records
