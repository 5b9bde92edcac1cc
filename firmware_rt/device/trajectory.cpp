#include "device/trajectory.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

namespace lancet::device {

Vec3 Trajectory::at(double s) const noexcept {
  if (t.empty()) return {};
  if (!(s > t.front())) return p.front();
  if (s >= t.back()) return p.back();
  const auto hi = static_cast<std::size_t>(std::upper_bound(t.begin(), t.end(), s) - t.begin());
  const std::size_t lo = hi - 1;
  const double w = (s - t[lo]) / (t[hi] - t[lo]);
  return p[lo] + (p[hi] - p[lo]) * w;
}

Result<HandTrajectories> load_trajectory_csv(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Error{ErrorCode::kNotFound, path + ": cannot open the trajectory file"};
  HandTrajectories hands;
  std::string line;
  int n = 0;
  bool header_allowed = true;
  static const char* kNames[4] = {"t_s", "x_mm", "y_mm", "z_mm"};
  while (std::getline(in, line)) {
    ++n;
    if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
    if (line.find_first_not_of(" \t\r,") == std::string::npos) continue;
    std::vector<std::string> cells;
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) {
      const auto b = c.find_first_not_of(" \t\r"), e = c.find_last_not_of(" \t\r");
      cells.push_back(b == std::string::npos ? std::string() : c.substr(b, e - b + 1));
    }
    const std::string where = path + ":" + std::to_string(n) + ": ";
    if (cells.size() < 4 || cells.size() > 6)
      return Error{ErrorCode::kInvalid,
                   where + "expected 4 to 6 values (t_s, x_mm, y_mm, z_mm[, tool[, hand]]), found " + std::to_string(cells.size())};
    double v[4];
    bool numbers = true;
    for (int i = 0; i < 4; ++i) {
      std::size_t used = 0;
      try {
        v[i] = std::stod(cells[static_cast<std::size_t>(i)], &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || used != cells[static_cast<std::size_t>(i)].size() || !std::isfinite(v[i])) {
        if (header_allowed && i == 0) {  // a first line whose first cell is no number: the header
          numbers = false;
          break;
        }
        return Error{ErrorCode::kInvalid, where + kNames[i] + ": expected a number, found '" + cells[static_cast<std::size_t>(i)] + "'"};
      }
    }
    header_allowed = false;
    if (!numbers) continue;  // the header line
    Hand hand = Hand::kRight;
    if (cells.size() == 6 && !cells[5].empty() && !hand_from_name(cells[5], hand))
      return Error{ErrorCode::kInvalid, where + "hand: expected right or left, found '" + cells[5] + "'"};
    Trajectory& tr = hands[hand_index(hand)];
    if (v[0] < 0) return Error{ErrorCode::kInvalid, where + "t_s: expected >= 0, found " + cells[0]};
    if (!tr.t.empty() && !(v[0] > tr.t.back()))
      return Error{ErrorCode::kInvalid, where + "t_s: times must increase (per hand): " + cells[0] + " follows " +
                                            std::to_string(tr.t.back()) + " of the " + hand_name(hand) + " hand"};
    tr.t.push_back(v[0]);
    tr.p.push_back(Vec3{v[1] * 1e-3, v[2] * 1e-3, v[3] * 1e-3});
    if (cells.size() >= 5 && !cells[4].empty()) {
      ToolMode mode{};
      if (!tool_from_name(cells[4], mode))
        return Error{ErrorCode::kInvalid, where + "tool: expected probe, scalpel, retractor or drill, found '" + cells[4] + "'"};
      tr.tools.push_back({v[0], mode});
    }
  }
  bool any = false;
  for (const Trajectory& tr : hands) any = any || !tr.t.empty();
  if (!any) return Error{ErrorCode::kInvalid, path + ": no trajectory points (lines of t_s, x_mm, y_mm, z_mm)"};
  return hands;
}

}  // namespace lancet::device
