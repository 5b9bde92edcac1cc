// The learning-curve CUSUM (records/cusum.hpp).

#include "records/cusum.hpp"

#include <cmath>

namespace lancet::records {

bool valid(const CusumRule& r) noexcept {
  const auto open01 = [](double x) { return x > 0 && x < 1; };
  return open01(r.p0) && open01(r.p1) && r.p0 < r.p1 && open01(r.alpha) && open01(r.beta);
}

CusumDesign design(const CusumRule& r) noexcept {
  const double p = std::log(r.p1 / r.p0);
  const double q = std::log((1 - r.p0) / (1 - r.p1));
  CusumDesign d;
  d.s = q / (p + q);
  d.h0 = std::log((1 - r.alpha) / r.beta) / (p + q);
  d.h1 = std::log((1 - r.beta) / r.alpha) / (p + q);
  return d;
}

CusumResult cusum(const CusumDesign& d, std::span<const bool> proficient) {
  CusumResult out;
  out.sum.reserve(proficient.size());
  double sum = 0;
  for (std::size_t i = 0; i < proficient.size(); ++i) {
    sum += proficient[i] ? -d.s : 1 - d.s;
    out.sum.push_back(sum);
    if (out.acceptable_at == 0 && sum <= -d.h0) out.acceptable_at = i + 1;
    if (out.unacceptable_at == 0 && sum >= d.h1) out.unacceptable_at = i + 1;
  }
  return out;
}

}  // namespace lancet::records
