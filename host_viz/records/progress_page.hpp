#pragma once
// A trainee's progress as one self-contained HTML page (inline CSS and SVG; no script, no
// network): where the trainee stands on each curriculum step (the next one highlighted), per
// scenario a CUSUM of failures (records/cusum.hpp) and a learning curve per metric (each
// attempt's value, its band's passing side shaded with the limit and mean lines, pass or fail
// marked), and every attempt with a link to its recording. Everything from the records is
// HTML-escaped. A pure function of what the store returned (allocating; tools only).

#include <string>
#include <vector>

#include "records/cusum.hpp"
#include "records/progress.hpp"

namespace lancet::records {

struct ProgressPageOptions {
  CusumRule cusum;       ///< the CUSUM's design, stated on the page
  std::string page_dir;  ///< the page's folder: absolute recording paths are linked relative to it ("" : as stored)
  /// Per attempt (the order of `attempts`), a link to its lancet-report page relative to the page,
  /// or "" where none could be written; empty: no report pages were made.
  std::vector<std::string> reports;
};

/// `p` is progress(trainee, curriculum, attempts); `attempts` are the trainee's, in the order made,
/// with their metrics (Store::attempts with a trainee filter and with_metrics).
[[nodiscard]] std::string progress_html(const Progress& p, const std::vector<Attempt>& attempts, const ProgressPageOptions& options);

}  // namespace lancet::records
