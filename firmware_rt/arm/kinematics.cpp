#include "arm/kinematics.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <numbers>
#include <string>

#include "arm/arm_config.hpp"

namespace lancet::arm {

namespace {

// Entry i of q, 0 past its end (release builds only; debug builds assert the length).
double joint(std::span<const double> q, int i) noexcept {
  const auto k = static_cast<std::size_t>(i);
  return k < q.size() ? q[k] : 0.0;
}

Vec3 column(const std::array<double, 9>& r, int c) noexcept {
  const auto k = static_cast<std::size_t>(c);
  return {r[k], r[3 + k], r[6 + k]};
}

// The transform of one standard DH link: Rot_z(theta) Trans_z(d) Trans_x(a) Rot_x(alpha).
Transform dh_transform(double a, double alpha, double d, double theta) noexcept {
  const double ct = std::cos(theta), st = std::sin(theta);
  const double ca = std::cos(alpha), sa = std::sin(alpha);
  Transform t;
  t.r = {ct, -st * ca, st * sa,  //
         st, ct * ca, -ct * sa,  //
         0, sa, ca};
  t.p = {a * ct, a * st, d};
  return t;
}

Transform link_transform(const DhLink& l, double q) noexcept {
  return l.type == JointType::kRevolute ? dh_transform(l.a, l.alpha, l.d, q + l.theta_offset)
                                        : dh_transform(l.a, l.alpha, l.d + q, l.theta_offset);
}

}  // namespace

Transform compose(const Transform& a, const Transform& b) noexcept {
  Transform t;
  for (std::size_t i = 0; i < 3; ++i) {
    for (std::size_t j = 0; j < 3; ++j) {
      t.r[3 * i + j] = a.r[3 * i] * b.r[j] + a.r[3 * i + 1] * b.r[3 + j] + a.r[3 * i + 2] * b.r[6 + j];
    }
  }
  t.p = apply(a, b.p);
  return t;
}

Vec3 apply(const Transform& t, Vec3 v) noexcept {
  const auto& r = t.r;
  return {r[0] * v.x + r[1] * v.y + r[2] * v.z + t.p.x,  //
          r[3] * v.x + r[4] * v.y + r[5] * v.z + t.p.y,  //
          r[6] * v.x + r[7] * v.y + r[8] * v.z + t.p.z};
}

Quat to_quat(const std::array<double, 9>& r) noexcept {
  // Shepperd's method: divide by the largest of the four candidates for stability.
  const double tr = r[0] + r[4] + r[8];
  Quat q;
  if (tr >= r[0] && tr >= r[4] && tr >= r[8]) {
    const double s = 2.0 * std::sqrt(std::max(0.0, 1.0 + tr));
    q = {0.25 * s, (r[7] - r[5]) / s, (r[2] - r[6]) / s, (r[3] - r[1]) / s};
  } else if (r[0] >= r[4] && r[0] >= r[8]) {
    const double s = 2.0 * std::sqrt(std::max(0.0, 1.0 + r[0] - r[4] - r[8]));
    q = {(r[7] - r[5]) / s, 0.25 * s, (r[1] + r[3]) / s, (r[2] + r[6]) / s};
  } else if (r[4] >= r[8]) {
    const double s = 2.0 * std::sqrt(std::max(0.0, 1.0 + r[4] - r[0] - r[8]));
    q = {(r[2] - r[6]) / s, (r[1] + r[3]) / s, 0.25 * s, (r[5] + r[7]) / s};
  } else {
    const double s = 2.0 * std::sqrt(std::max(0.0, 1.0 + r[8] - r[0] - r[4]));
    q = {(r[3] - r[1]) / s, (r[2] + r[6]) / s, (r[5] + r[7]) / s, 0.25 * s};
  }
  if (q.w < 0) q = {-q.w, -q.x, -q.y, -q.z};
  const double n = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  return n > 0 ? Quat{q.w / n, q.x / n, q.y / n, q.z / n} : Quat{};
}

Pose to_pose(const Transform& t) noexcept { return {t.p, to_quat(t.r)}; }

// ---------------------------------------------------------------------------------------------
// DhChain

DhChain::DhChain(std::span<const DhLink> links, Vec3 base_offset, Vec3 tool_offset) noexcept
    : base_offset_(base_offset), tool_offset_(tool_offset) {
  assert(!links.empty() && links.size() <= static_cast<std::size_t>(kMaxJoints) &&
         "DhChain: 1..kMaxJoints links");
  n_ = static_cast<int>(std::min(links.size(), static_cast<std::size_t>(kMaxJoints)));
  std::copy_n(links.begin(), n_, links_.begin());
}

Transform DhChain::forward_transform(std::span<const double> q) const noexcept {
  assert(q.size() == static_cast<std::size_t>(n_) && "DhChain::forward_transform: q has joint_count entries");
  Transform t;
  t.p = base_offset_;
  for (int i = 0; i < n_; ++i) t = compose(t, link_transform(links_[static_cast<std::size_t>(i)], joint(q, i)));
  t.p = apply(t, tool_offset_);
  return t;
}

Pose DhChain::forward(std::span<const double> q) const noexcept { return to_pose(forward_transform(q)); }

Vec3 DhChain::position(std::span<const double> q) const noexcept { return forward_transform(q).p; }

SpatialJacobian DhChain::spatial_jacobian(std::span<const double> q) const noexcept {
  assert(q.size() == static_cast<std::size_t>(n_) && "DhChain::spatial_jacobian: q has joint_count entries");
  // Joint i turns about / slides along z_{i-1} through o_{i-1}: keep those while walking the chain.
  std::array<Vec3, kMaxJoints> axis{}, origin{};
  Transform t;
  t.p = base_offset_;
  for (int i = 0; i < n_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    axis[k] = column(t.r, 2);
    origin[k] = t.p;
    t = compose(t, link_transform(links_[k], joint(q, i)));
  }
  const Vec3 tip = apply(t, tool_offset_);
  SpatialJacobian j;
  j.n = n_;
  for (int i = 0; i < n_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (links_[k].type == JointType::kRevolute) {
      j.linear[k] = cross(axis[k], tip - origin[k]);
      j.angular[k] = axis[k];
    } else {
      j.linear[k] = axis[k];
      j.angular[k] = {};
    }
  }
  return j;
}

Jacobian DhChain::jacobian(std::span<const double> q) const noexcept {
  const SpatialJacobian s = spatial_jacobian(q);
  Jacobian j;
  j.n = s.n;
  j.column = s.linear;
  return j;
}

// ---------------------------------------------------------------------------------------------
// PhantomArm

Vec3 PhantomArm::position(std::span<const double> q) const noexcept {
  assert(q.size() == kJoints && "PhantomArm::position: q has 3 entries");
  const double q1 = joint(q, 0), q2 = joint(q, 1), q3 = joint(q, 2);
  const double r = l1 * std::cos(q2) + l2 * std::sin(q3);
  const double h = l1 * std::sin(q2) - l2 * std::cos(q3);
  return base_offset + Vec3{r * std::cos(q1), r * std::sin(q1), h};
}

Pose PhantomArm::forward(std::span<const double> q) const noexcept { return {position(q), Quat{}}; }

Jacobian PhantomArm::jacobian(std::span<const double> q) const noexcept {
  assert(q.size() == kJoints && "PhantomArm::jacobian: q has 3 entries");
  const double q1 = joint(q, 0), q2 = joint(q, 1), q3 = joint(q, 2);
  const double c1 = std::cos(q1), s1 = std::sin(q1);
  const double r = l1 * std::cos(q2) + l2 * std::sin(q3);
  // ∂r/∂q2, ∂r/∂q3, ∂h/∂q2, ∂h/∂q3
  const double r2 = -l1 * std::sin(q2), r3 = l2 * std::cos(q3);
  const double h2 = l1 * std::cos(q2), h3 = l2 * std::sin(q3);
  Jacobian j;
  j.n = kJoints;
  j.column[0] = {-r * s1, r * c1, 0};
  j.column[1] = {r2 * c1, r2 * s1, h2};
  j.column[2] = {r3 * c1, r3 * s1, h3};
  return j;
}

DhChain PhantomArm::to_dh_chain() const noexcept {
  const double half_pi = std::numbers::pi / 2;
  const std::array<DhLink, 3> links{{
      {JointType::kRevolute, 0, half_pi, 0, 0},
      {JointType::kRevolute, l1, 0, 0, 0},
      {JointType::kRevolute, l2, 0, 0, -half_pi},
  }};
  return DhChain(links, base_offset);
}

std::array<double, 3> PhantomArm::to_dh_joints(std::span<const double> q) noexcept {
  return {joint(q, 0), joint(q, 1), joint(q, 2) - joint(q, 1)};
}

// ---------------------------------------------------------------------------------------------
// Torques

JointArray joint_torques(const Jacobian& j, Vec3 force) noexcept {
  JointArray tau{};
  const int n = std::clamp(j.n, 0, kMaxJoints);
  for (int i = 0; i < n; ++i) {
    const auto k = static_cast<std::size_t>(i);
    tau[k] = dot(j.column[k], force);
  }
  return tau;
}

JointArray joint_torques(const SpatialJacobian& j, Vec3 force, Vec3 moment) noexcept {
  JointArray tau{};
  const int n = std::clamp(j.n, 0, kMaxJoints);
  for (int i = 0; i < n; ++i) {
    const auto k = static_cast<std::size_t>(i);
    tau[k] = dot(j.linear[k], force) + dot(j.angular[k], moment);
  }
  return tau;
}

// ---------------------------------------------------------------------------------------------
// Kinematics

namespace {
Vec3 cartesian_position(std::span<const double> q) noexcept {
  return q.size() >= 3 ? Vec3{q[0], q[1], q[2]} : Vec3{};
}
}  // namespace

std::string_view model_name(KinematicModel m) noexcept {
  switch (m) {
    case KinematicModel::kDh: return "dh";
    case KinematicModel::kPhantom: return "phantom";
    case KinematicModel::kCartesian: return "cartesian";
    case KinematicModel::kDelta: return "delta";
  }
  return "unknown";
}

int Kinematics::joint_count() const noexcept {
  switch (model_) {
    case KinematicModel::kDh: return dh_.joint_count();
    case KinematicModel::kPhantom: return PhantomArm::joint_count();
    case KinematicModel::kCartesian: return 3;
    case KinematicModel::kDelta: return DeltaArm::joint_count();
  }
  return 0;
}

Vec3 Kinematics::position(std::span<const double> q) const noexcept {
  switch (model_) {
    case KinematicModel::kDh: return dh_.position(q);
    case KinematicModel::kPhantom: return phantom_.position(q);
    case KinematicModel::kCartesian: return cartesian_position(q);
    case KinematicModel::kDelta: return delta_.position(q);
  }
  return {};
}

Pose Kinematics::forward(std::span<const double> q) const noexcept {
  switch (model_) {
    case KinematicModel::kDh: return dh_.forward(q);
    case KinematicModel::kPhantom: return phantom_.forward(q);
    case KinematicModel::kCartesian: return Pose{cartesian_position(q), Quat{}};
    case KinematicModel::kDelta: return delta_.forward(q);
  }
  return {};
}

Jacobian Kinematics::jacobian(std::span<const double> q) const noexcept {
  switch (model_) {
    case KinematicModel::kDh: return dh_.jacobian(q);
    case KinematicModel::kPhantom: return phantom_.jacobian(q);
    case KinematicModel::kCartesian: {
      Jacobian j;
      j.n = 3;
      j.column[0] = {1, 0, 0}, j.column[1] = {0, 1, 0}, j.column[2] = {0, 0, 1};
      return j;
    }
    case KinematicModel::kDelta: return delta_.jacobian(q);
  }
  return {};
}

Jacobian Kinematics::position_and_jacobian(std::span<const double> q, Vec3& position) const noexcept {
  if (model_ == KinematicModel::kDelta) {
    position = delta_.position(q);
    return delta_.jacobian_at(q, position);
  }
  position = this->position(q);
  return jacobian(q);
}

namespace {

bool finite(Vec3 v) { return is_finite(v); }

Error invalid(const std::string& what) { return Error{ErrorCode::kInvalid, "make_kinematics: " + what}; }

}  // namespace

Result<Kinematics> make_kinematics(const ArmConfig& config) {
  const KinematicsConfig& k = config.kinematics;
  if (!finite(k.base_offset)) return invalid("kinematics.base_offset is not finite");
  if (k.model == KinematicModel::kDelta) {
    if (const char* problem = delta_geometry_problem(k.delta)) return invalid(std::string("kinematics (delta): ") + problem);
    return Kinematics(DeltaArm(k.delta, k.base_offset, k.delta_axes));
  }
  if (k.model == KinematicModel::kPhantom) {
    if (!(std::isfinite(k.l1) && k.l1 > 0)) return invalid("kinematics.l1 must be > 0 m, found " + std::to_string(k.l1));
    if (!(std::isfinite(k.l2) && k.l2 > 0)) return invalid("kinematics.l2 must be > 0 m, found " + std::to_string(k.l2));
    return Kinematics(PhantomArm{k.l1, k.l2, k.base_offset});
  }
  if (k.links.empty() || k.links.size() > static_cast<std::size_t>(kMaxJoints)) {
    return invalid("kinematics.links must have 1.." + std::to_string(kMaxJoints) + " links, found " +
                   std::to_string(k.links.size()));
  }
  if (!finite(k.tool_offset)) return invalid("kinematics.tool_offset is not finite");
  for (std::size_t i = 0; i < k.links.size(); ++i) {
    const DhLink& l = k.links[i];
    if (!(std::isfinite(l.a) && std::isfinite(l.alpha) && std::isfinite(l.d) && std::isfinite(l.theta_offset))) {
      return invalid("kinematics.links[" + std::to_string(i) + "] has a non-finite parameter");
    }
  }
  return Kinematics(DhChain(k.links, k.base_offset, k.tool_offset));
}

}  // namespace lancet::arm
