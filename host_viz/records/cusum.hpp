#pragma once
// The CUSUM of a trainee's failures at one scenario: the standard cumulative-sum chart of surgical
// learning curves (Williams et al. 1992, Bolsin & Colson 2000), built on Wald's sequential
// probability ratio test between an acceptable failure rate p0 and an unacceptable one p1.
//
// With P = ln(p1/p0) and Q = ln((1-p0)/(1-p1)), each attempt moves the sum by
//   +(1 - s) on a failure and -s on a success, where s = Q / (P + Q);
// s is the failure rate at which the sum drifts neither up nor down (between p0 and p1). The
// decision limits, with alpha the chance of calling an acceptable trainee unacceptable and beta
// the reverse, are
//   h1 = ln((1 - beta) / alpha) / (P + Q)   reached from below: the failure rate is unacceptable (p1)
//   h0 = ln((1 - alpha) / beta) / (P + Q)   -h0 reached from above: it is acceptable (p0)
// The sum starts at 0 and is not reset: the chart is the whole learning curve.
//
// A failure is an attempt that is not proficient (records::Attempt::proficient). Pure functions;
// cusum_path allocates its result.

#include <cstddef>
#include <span>
#include <vector>

namespace lancet::records {

/// The rates and error chances the chart is designed with.
struct CusumRule {
  double p0 = 0.2;     ///< acceptable failure rate, 0 < p0 < p1
  double p1 = 0.4;     ///< unacceptable failure rate, p0 < p1 < 1
  double alpha = 0.1;  ///< type I error: calling a p0 trainee p1, (0, 1)
  double beta = 0.1;   ///< type II error: calling a p1 trainee p0, (0, 1)
};

/// The chart's increments and decision limits (see the file comment).
struct CusumDesign {
  double s = 0;   ///< subtracted on a success; 1 - s is added on a failure
  double h0 = 0;  ///< the acceptable-performance limit is at -h0
  double h1 = 0;  ///< the unacceptable-performance limit is at +h1
};

/// True when 0 < p0 < p1 < 1 and alpha, beta are in (0, 1).
[[nodiscard]] bool valid(const CusumRule& r) noexcept;

/// The design of a valid rule.
[[nodiscard]] CusumDesign design(const CusumRule& r) noexcept;

/// What the chart says after the attempts so far.
struct CusumResult {
  std::vector<double> sum;  ///< the sum after each attempt (sum[i]: after attempt i + 1)
  std::size_t acceptable_at = 0;    ///< the first attempt (1-based) at which the sum reached -h0; 0: never
  std::size_t unacceptable_at = 0;  ///< the first attempt (1-based) at which it reached +h1; 0: never
};

/// The chart of `proficient` (the attempts' results in the order made; true: a success).
[[nodiscard]] CusumResult cusum(const CusumDesign& d, std::span<const bool> proficient);

}  // namespace lancet::records
