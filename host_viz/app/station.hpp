#pragma once
// Station: lancet-viz --trainee ID. Each finished recording is the trainee's attempt: it goes into
// the station's outbox (records/outbox.hpp) and is delivered to the records (scored and stored)
// on a thread of its own, never on the frame loop; what cannot be delivered (the database cannot
// be reached) waits there for the next delivery, the next start, or `lancet-records deliver`.
// The trainee's standing in the curriculum (the step they are on, its attempts and proficient
// ones, the next scenario), or how many attempts wait while the records cannot be reached, is
// refreshed after each delivery for the panel, and printed on stderr each time it changes.
//
// Threads: start, recording_path, attempt_recorded and finish on the app's thread; panel_lines
// from any. Allocates; not real-time.

#include <chrono>
#include <memory>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "lancet/shared_model/result.hpp"

namespace lancet::viz {

struct StationOptions {
  std::string trainee;  ///< --trainee: whose attempts these are
  std::string db;       ///< --db: the records (an SQLite file or a postgresql:// URL)
  std::string outbox;   ///< --outbox ("" records::default_outbox_path(db))
  std::string version;  ///< this build's, stored as the attempts' scored_by
};

class Station {
 public:
  /// Checks that the trainee exists (an error, ErrorCode::kNotFound, naming it when not); when
  /// the records cannot be reached, says so on stderr and goes on. Then delivers what waits in
  /// the outbox, in the background.
  [[nodiscard]] static Result<std::unique_ptr<Station>> start(StationOptions options);
  ~Station();
  Station(const Station&) = delete;
  Station& operator=(const Station&) = delete;

  /// Where an attempt is recorded when no --record was given: a new name in the outbox folder
  /// each call.
  [[nodiscard]] std::string recording_path();
  /// Whether `path` is one of recording_path()'s.
  [[nodiscard]] bool records_into_outbox(const std::string& path) const;
  /// A recording finished: into the outbox (moved when it is one of recording_path()'s, else
  /// linked or copied: the file stays where --record put it), and a delivery asked for.
  void attempt_recorded(const std::string& path);
  /// The trainee's standing, one line each, for the panel (alert: the records cannot be reached).
  [[nodiscard]] std::vector<std::pair<std::string, bool>> panel_lines() const;
  /// The run's end: waits up to `wait` for the deliveries asked for; what is not delivered by
  /// then stays in the outbox (said on stderr). Idempotent.
  void finish(std::chrono::milliseconds wait);

  struct Shared;  // the state the delivery thread shares (it may outlive this object)

 private:
  explicit Station(std::shared_ptr<Shared> shared);
  void ask_delivery();
  std::shared_ptr<Shared> shared_;
  std::thread thread_;  ///< the deliveries; joined by finish, or left to end with the process
  bool finished_ = false;
  int recordings_ = 0;  ///< recording_path()'s names so far
};

}  // namespace lancet::viz
