#pragma once
// Arm kinematics built from a config: a general serial chain from Denavit-Hartenberg parameters
// (standard convention, any number of joints up to kMaxJoints), the closed-form 3-DOF
// PHANToM-style arm and the three-leg delta (parallel) arm of the Novint Falcon (arm/delta_arm.hpp),
// each giving the tool point, its pose and the Jacobian of the tool point, and the
// Jacobian-transpose map from a tool force to joint torques. Models are small fixed-size values
// built once at configure time (make_kinematics); forward, jacobian and joint_torques never
// allocate and are real-time safe.
//
// Frames: every model works in the device base frame (m, rad). Where a config says so, a constant
// translation (base_offset) moves the model's own origin within that frame; a rotated mount is the
// caller's business (the device-to-world registration).
//
// Joint vectors are spans of joint_count() doubles: rad for revolute joints, m for prismatic ones.
// Passing a span of another length is a programmer error (asserted); in release builds missing
// entries read as 0 and extra entries are ignored.

#include <array>
#include <cstdint>
#include <span>
#include <string_view>
#include <type_traits>

#include "arm/delta_arm.hpp"
#include "arm/jacobian.hpp"
#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::arm {

struct ArmConfig;

enum class JointType : std::uint8_t {
  kRevolute,   ///< the joint variable (rad) adds to theta
  kPrismatic,  ///< the joint variable (m) adds to d
};

enum class KinematicModel : std::uint8_t {
  kDh,       ///< DhChain
  kPhantom,  ///< PhantomArm
  kCartesian,  ///< three prismatic joints along x, y, z: q is the position (the built-in simulated stylus)
  kDelta,    ///< DeltaArm (appended: the values travel in the servo model's bytes)
};

/// The model's name as a config writes it: "dh", "phantom", "cartesian" (no config key), "delta".
[[nodiscard]] std::string_view model_name(KinematicModel m) noexcept;

/// Rigid transform: row-major rotation (r[3*row + col]) and translation (m).
struct Transform {
  std::array<double, 9> r{1, 0, 0, 0, 1, 0, 0, 0, 1};
  Vec3 p{};
};

/// a ∘ b: the transform that applies b first, then a.
Transform compose(const Transform& a, const Transform& b) noexcept;
/// Rotates and translates v.
Vec3 apply(const Transform& t, Vec3 v) noexcept;
/// The unit quaternion of a rotation matrix (w >= 0).
Quat to_quat(const std::array<double, 9>& r) noexcept;
/// The pose (position, orientation) of a transform.
Pose to_pose(const Transform& t) noexcept;

/// One link in standard (distal) Denavit-Hartenberg form: frame i follows frame i-1 by
///   Rot_z(theta) · Trans_z(d) · Trans_x(a) · Rot_x(alpha)
/// with theta = q_i + theta_offset for a revolute joint and d = q_i + d for a prismatic one
/// (theta_offset is then the fixed theta). Joint i moves about / along z_{i-1}.
struct DhLink {
  JointType type = JointType::kRevolute;
  double a = 0;             ///< m, link length along x_i
  double alpha = 0;         ///< rad, link twist about x_i
  double d = 0;             ///< m, offset along z_{i-1} (added to q for a prismatic joint)
  double theta_offset = 0;  ///< rad, angle about z_{i-1} (added to q for a revolute joint)
};

/// Serial chain of 1..kMaxJoints DH links. The tool point is tool_offset (m, in the last link's
/// frame n); the chain's frame 0 sits at base_offset (m) in the device frame, axes aligned.
class DhChain {
 public:
  DhChain() = default;
  /// links.size() must be in 1..kMaxJoints (asserted; extra links are dropped in release).
  explicit DhChain(std::span<const DhLink> links, Vec3 base_offset = {}, Vec3 tool_offset = {}) noexcept;

  [[nodiscard]] int joint_count() const noexcept { return n_; }
  [[nodiscard]] std::span<const DhLink> links() const noexcept { return {links_.data(), static_cast<std::size_t>(n_)}; }
  [[nodiscard]] Vec3 base_offset() const noexcept { return base_offset_; }
  [[nodiscard]] Vec3 tool_offset() const noexcept { return tool_offset_; }

  /// The tool frame (last link frame moved to the tool point) in the device frame. Real-time safe.
  [[nodiscard]] Transform forward_transform(std::span<const double> q) const noexcept;
  /// forward_transform as a Pose. Real-time safe.
  [[nodiscard]] Pose forward(std::span<const double> q) const noexcept;
  /// The tool point (m, device frame). Real-time safe.
  [[nodiscard]] Vec3 position(std::span<const double> q) const noexcept;
  /// Linear Jacobian of the tool point. Real-time safe.
  [[nodiscard]] Jacobian jacobian(std::span<const double> q) const noexcept;
  /// Geometric 6 × n Jacobian of the tool frame. Real-time safe.
  [[nodiscard]] SpatialJacobian spatial_jacobian(std::span<const double> q) const noexcept;

 private:
  std::array<DhLink, kMaxJoints> links_{};
  int n_ = 0;
  Vec3 base_offset_{};
  Vec3 tool_offset_{};
};

/// Closed-form PHANToM Premium-style 3-DOF arm (capstan-driven parallelogram), in its base frame:
/// origin on the shoulder axis where it meets the vertical base-yaw axis, z up, x the reach
/// direction at q1 = 0, y = z × x.
///   q1  base yaw about +z; positive turns the arm counter-clockwise seen from above.
///   q2  shoulder: elevation of the upper arm (length l1) above the horizontal; positive raises
///       the elbow.
///   q3  elbow: angle of the forearm (length l2) from the downward vertical, positive swinging
///       the tool point outward (away from the yaw axis). Absolute, not relative to the upper arm:
///       the parallelogram drive makes the elbow motor measure the forearm against the base.
/// With r = l1 cos q2 + l2 sin q3 (horizontal reach) and h = l1 sin q2 − l2 cos q3 (height):
///   p(q) = base_offset + (r cos q1, r sin q1, h).
/// At q = 0 the upper arm points along +x and the forearm hangs straight down: p = (l1, 0, −l2);
/// base_offset = (−l1, 0, l2) puts that home position at the origin.
/// The same chain in standard DH form (to_dh_chain) is
///   link 1: a = 0,  alpha = +90°, d = 0, theta_offset = 0
///   link 2: a = l1, alpha = 0,    d = 0, theta_offset = 0
///   link 3: a = l2, alpha = 0,    d = 0, theta_offset = −90°
/// with DH joint variables (q1, q2, q3 − q2) (to_dh_joints).
struct PhantomArm {
  double l1 = 0;      ///< m, upper arm (shoulder to elbow), > 0
  double l2 = 0;      ///< m, forearm (elbow to tool point), > 0
  Vec3 base_offset{}; ///< m, the model origin in the device frame

  static constexpr int kJoints = 3;
  [[nodiscard]] static constexpr int joint_count() noexcept { return kJoints; }

  /// The tool point (m, device frame). Real-time safe.
  [[nodiscard]] Vec3 position(std::span<const double> q) const noexcept;
  /// Tool point and orientation; the 3-DOF arm senses no stylus orientation, so the orientation
  /// is the identity. Real-time safe.
  [[nodiscard]] Pose forward(std::span<const double> q) const noexcept;
  /// Linear Jacobian of the tool point, closed form. Real-time safe.
  [[nodiscard]] Jacobian jacobian(std::span<const double> q) const noexcept;

  /// The equivalent standard-DH chain (see above), with the same base offset.
  [[nodiscard]] DhChain to_dh_chain() const noexcept;
  /// PHANToM joint angles to the DH chain's joint variables: (q1, q2, q3 − q2).
  [[nodiscard]] static std::array<double, 3> to_dh_joints(std::span<const double> q) noexcept;
};

/// τ = Jᵀ F: joint torques (N·m for revolute, N for prismatic joints) that render the force F (N,
/// device frame) at the tool point; entries at and beyond j.n are zero. Real-time safe.
[[nodiscard]] JointArray joint_torques(const Jacobian& j, Vec3 force) noexcept;
/// τ = Jᵀ [F; M] for a force F (N) and a moment M (N·m) on the tool frame. Real-time safe.
[[nodiscard]] JointArray joint_torques(const SpatialJacobian& j, Vec3 force, Vec3 moment) noexcept;

/// The arm's kinematic model as one value (any kind), so the servo loop holds it by value.
class Kinematics {
 public:
  explicit Kinematics(const DhChain& chain) noexcept : model_(KinematicModel::kDh), dh_(chain) {}
  explicit Kinematics(const PhantomArm& arm) noexcept : model_(KinematicModel::kPhantom), phantom_(arm) {}
  explicit Kinematics(const DeltaArm& arm) noexcept : model_(KinematicModel::kDelta), delta_(arm) {}
  /// Three prismatic joints along x, y, z: position = q, Jacobian = identity.
  [[nodiscard]] static Kinematics cartesian() noexcept { return Kinematics(KinematicModel::kCartesian); }

  [[nodiscard]] KinematicModel model() const noexcept { return model_; }
  [[nodiscard]] int joint_count() const noexcept;
  /// The tool point (m, device frame). Real-time safe.
  [[nodiscard]] Vec3 position(std::span<const double> q) const noexcept;
  /// The tool pose (identity orientation for the PHANToM and delta models). Real-time safe.
  [[nodiscard]] Pose forward(std::span<const double> q) const noexcept;
  /// Linear Jacobian of the tool point. Real-time safe.
  [[nodiscard]] Jacobian jacobian(std::span<const double> q) const noexcept;
  /// position(q) and jacobian(q) from one forward solve (the delta model solves its forward
  /// kinematics iteratively; the others just call both). The same bits as the two calls.
  /// Real-time safe.
  [[nodiscard]] Jacobian position_and_jacobian(std::span<const double> q, Vec3& position) const noexcept;

  /// The model itself; nullptr when the model is of another kind.
  [[nodiscard]] const DhChain* dh_chain() const noexcept { return model_ == KinematicModel::kDh ? &dh_ : nullptr; }
  [[nodiscard]] const PhantomArm* phantom() const noexcept {
    return model_ == KinematicModel::kPhantom ? &phantom_ : nullptr;
  }
  [[nodiscard]] const DeltaArm* delta() const noexcept { return model_ == KinematicModel::kDelta ? &delta_ : nullptr; }

 private:
  explicit Kinematics(KinematicModel m) noexcept : model_(m) {}
  KinematicModel model_;
  // The delta shares the DH chain's bytes: sizeof(Kinematics), and with it the servo model's
  // layout (servo::kServoModelLayout), stays what it was before the delta model, so recordings of
  // earlier builds still replay. model_ says which member is live.
  union {
    DhChain dh_{};
    DeltaArm delta_;
  };
  PhantomArm phantom_{};
};
static_assert(sizeof(DeltaArm) <= sizeof(DhChain) && alignof(DeltaArm) <= alignof(DhChain), "the delta fits in the DH chain's bytes");
static_assert(std::is_trivially_copyable_v<Kinematics>, "Kinematics travels as bytes (the servo model)");

/// Builds the kinematic model of a loaded config (configure time). Fails with kInvalid, naming the
/// field, when the config was built by hand and breaks what the loader checks (no links or more
/// than kMaxJoints, non-positive or non-finite lengths, a delta geometry delta_geometry_problem
/// rejects).
Result<Kinematics> make_kinematics(const ArmConfig& config);

}  // namespace lancet::arm
