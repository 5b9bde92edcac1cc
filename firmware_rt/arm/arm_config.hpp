#pragma once
// ArmConfig: one haptic arm as data, loaded from a TOML file in hw_configs/ (schema:
// hw_configs/README.md). The file states its units in its key names (length_mm, offset_deg,
// watchdog_period_ms, ...); everything here is SI: m, rad, N, N·m, A, s.
//
// Loading validates the whole file and reports every problem at once (file:line:column, the dotted
// field path, expected vs found): unknown keys, missing required keys, wrong types, values out of
// range, joint counts that disagree between sections, a bus section that does not match the
// backend. Configure time only: nothing here is for the real-time path except the two small
// conversion helpers at the end.

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "arm/kinematics.hpp"
#include "config/error.hpp"
#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::arm {

// ---------------------------------------------------------------------------------------------
// The config

enum class Backend : std::uint8_t { kSim, kUsb, kModbus, kCanopen, kFalcon };

struct KinematicsConfig {
  KinematicModel model = KinematicModel::kPhantom;
  Vec3 base_offset{};           ///< m, model origin in the device frame
  // model = phantom
  double l1 = 0;                ///< m, upper arm
  double l2 = 0;                ///< m, forearm
  // model = dh
  std::vector<DhLink> links;    ///< one per joint (m, rad)
  Vec3 tool_offset{};           ///< m, tool point in the last link frame
  // model = delta
  DeltaGeometry delta{};        ///< m, rad (Stamper's a..f, r, s and the leg angles)
  DeltaAxes delta_axes = DeltaAxes::kModel;  ///< `axes`: "model" or "z_up" (arm/delta_arm.hpp)

  /// Joints of the model: 3 for phantom, delta (and cartesian), links.size() for dh.
  [[nodiscard]] int joint_count() const noexcept {
    return model == KinematicModel::kDh ? static_cast<int>(links.size()) : 3;
  }
};

/// One joint's sensing. Joint position from a raw encoder count c:
///   revolute:  q = direction · 2π · c / (counts_per_rev · gear_ratio) + offset        (rad)
///   prismatic: q = direction · lead · c / (counts_per_rev · gear_ratio) + offset      (m)
struct JointConfig {
  std::string name;
  JointType type = JointType::kRevolute;  ///< from the kinematic model
  std::int64_t counts_per_rev = 0;        ///< encoder counts per motor revolution (after quadrature), > 0
  double gear_ratio = 1;                  ///< motor revolutions per joint output revolution, > 0
  int direction = 1;                      ///< +1 or −1: sign from motor to joint (counts and torque)
  double offset = 0;                      ///< rad (m for prismatic): joint position at count 0
  double min = 0, max = 0;                ///< rad (m for prismatic): soft limits, min < max
  double lead = 0;                        ///< m of travel per output revolution (prismatic only)
  /// rad/s (m/s for prismatic), > 0: the fastest the joint can really move. An encoder reading
  /// further from the last good one than this speed allows is a glitch (device::Device counts it).
  double max_speed = kDefaultMaxSpeedDegS * 3.14159265358979323846 / 180.0;
  static constexpr double kDefaultMaxSpeedDegS = 1800;  ///< max_speed_deg_s when the file has none
  static constexpr double kDefaultMaxSpeedMmS = 3000;   ///< max_speed_mm_s when the file has none
};

/// One joint's motor.
struct ActuatorConfig {
  std::string name;                 ///< optional label
  double torque_constant = 0;       ///< N·m/A, > 0
  double peak_current = 0;          ///< A, >= continuous_current
  double continuous_current = 0;    ///< A, > 0
  [[nodiscard]] double peak_torque() const noexcept { return torque_constant * peak_current; }              ///< N·m, motor shaft
  [[nodiscard]] double continuous_torque() const noexcept { return torque_constant * continuous_current; }  ///< N·m, motor shaft
};

/// Binary field types of USB reports and Modbus registers (kF32: IEEE 754 single precision).
enum class FieldType : std::uint8_t { kU8, kI8, kU16, kI16, kU32, kI32, kF32 };
/// Size of one value of the type in bytes.
[[nodiscard]] int field_size(FieldType t) noexcept;

struct SimBusConfig {
  double stylus_mass = 0.15;       ///< kg
  double hand_stiffness = 1500;    ///< N/m
  double hand_damping = 21;        ///< N·s/m
  std::int64_t encoder_noise_counts = 0;  ///< ± counts of uniform noise on every encoder
};

enum class ByteOrder : std::uint8_t { kLittle, kBig };

/// One named bit of a device's status word: active when it reads 1, or 0 when active_low.
struct StatusBit {
  int bit = -1;             ///< 0..word width − 1; −1: not mapped
  bool active_low = false;
  [[nodiscard]] bool mapped() const noexcept { return bit >= 0; }
  /// Whether the bit is mapped and active in `word`. Real-time safe.
  [[nodiscard]] bool active(std::uint32_t word) const noexcept {
    return bit >= 0 && bit < 32 && (((word >> bit) & 1u) != 0) != active_low;
  }
};

/// The bits of a status word the USB and Modbus drivers act on, each optional (`bits = {...}` in
/// the config). While the driver has the drives enabled, an active fault, estop or comm_lost, or
/// an inactive ready or enabled, is a device fault (read() → kDeviceFault, named in the fault
/// detail); activate() and rearm() wait for them to settle.
struct StatusBits {
  StatusBit ready;      ///< the drive is ready to run (powered, no fault)
  StatusBit fault;      ///< the drive has faulted; latched until a fault reset
  StatusBit enabled;    ///< the drive is enabled (follows the setpoints)
  StatusBit estop;      ///< an emergency stop is pressed
  StatusBit comm_lost;  ///< the drive's own watchdog tripped: the host's heartbeat stopped
};

/// What a setpoint field carries, in physical units (physical = scale · raw + bias).
enum class SetpointKind : std::uint8_t {
  kCurrent,  ///< motor current, A (`current_command`)
  kTorque,   ///< motor torque at the motor shaft (before the gear), N·m (`torque_command`)
};

/// A field of a USB report: byte offset into the report (the report ID byte, when there is one,
/// is byte 0). Per-joint fields hold joint_count consecutive values.
struct ReportField {
  std::uint32_t offset = 0;
  FieldType type = FieldType::kU8;
  ByteOrder byte_order = ByteOrder::kLittle;  ///< of this field's bytes ([bus.usb] byte_order unless the field says)
  double scale = 1;  ///< physical = scale · raw + bias (encoders: counts; setpoints: A or N·m)
  double bias = 0;
};

struct UsbBusConfig {
  std::uint16_t vid = 0, pid = 0;
  int interface_number = 0;          ///< 0..255
  std::uint8_t endpoint_in = 0x81;   ///< interrupt IN, 0x81..0x8F
  std::uint8_t endpoint_out = 0x01;  ///< interrupt OUT, 0x01..0x0F
  ByteOrder byte_order = ByteOrder::kLittle;  ///< the default of the fields
  double timeout = 0.002;            ///< s, per transfer
  /// s: the device's own watchdog, when the OUT report has a heartbeat: the device goes torque-free
  /// when the heartbeat stops changing this long (the device's firmware setting; 0: off).
  double drive_watchdog = 0;
  // device → host
  std::uint32_t in_size = 0;                 ///< bytes
  std::optional<std::uint8_t> in_report_id;  ///< byte 0 when present
  ReportField encoder_counts;                ///< per joint: counts = scale · raw + bias
  std::optional<ReportField> buttons, status;
  StatusBits status_bits;                    ///< meaning of the status field's bits
  // host → device
  std::uint32_t out_size = 0;
  std::optional<std::uint8_t> out_report_id;
  ReportField setpoint;                      ///< per joint: A or N·m (setpoint_kind) = scale · raw + bias
  SetpointKind setpoint_kind = SetpointKind::kCurrent;
  std::optional<ReportField> enable;         ///< written in every OUT report: enable_on / enable_off
  std::uint32_t enable_on = 1, enable_off = 0;
  std::optional<ReportField> fault_reset;    ///< one report with fault_reset_value on rearm / activate
  std::uint32_t fault_reset_value = 0;
  std::optional<ReportField> heartbeat;      ///< counts up by one in every OUT report (wraps)
};

/// When the Falcon backend uploads the firmware.
enum class FirmwareUpload : std::uint8_t {
  kWhenNeeded,  ///< only when the Falcon does not already answer in normal mode (it keeps its firmware until unplugged)
  kAlways,      ///< at every configure and reconnect
};

/// [bus.falcon]: a Novint Falcon, an FTDI USB-serial chip in front of the Falcon's own
/// microcontroller (device/falcon_protocol.hpp).
struct FalconBusConfig {
  std::uint16_t vid = 0x0403, pid = 0xCB48;
  int index = 0;                 ///< which Falcon, when several are plugged in (libusb's order)
  std::string firmware;          ///< the firmware file the user supplies (relative: to the config's folder)
  FirmwareUpload upload = FirmwareUpload::kWhenNeeded;
  double timeout = 0.002;        ///< s, how long a read waits for the reply to the last command
  /// Motor command counts per N·m of torque at a thigh (signed: libnifalcon's −10 000; positive
  /// encoder counts raise the thigh angle, a positive command lowers it).
  double motor_command_per_nm = -10'000;
  double homing_timeout = 30;    ///< s that activate() waits for the three home switches
};

enum class ModbusTransport : std::uint8_t { kTcp, kRtu };
enum class RegisterTable : std::uint8_t { kInput, kHolding };
enum class Parity : std::uint8_t { kNone, kEven, kOdd };

/// A value (or one per joint) in the Modbus register space: 16-bit types take one register,
/// 32-bit types (u32, i32, f32) two.
struct RegisterField {
  RegisterTable table = RegisterTable::kInput;
  /// Protocol address (0-based) of each value: one per joint for per-joint entries (the loader
  /// expands `address = N` to N, N + w, N + 2w, … with w the registers per value), else one.
  std::vector<std::uint16_t> address;
  FieldType type = FieldType::kU16;       ///< u16, i16, u32, i32, f32
  bool high_word_first = true;            ///< 32-bit values: the register with the high half first
  ByteOrder byte_order = ByteOrder::kBig; ///< bytes within each register (big: the Modbus standard)
  double scale = 1;  ///< physical = scale · raw + bias (encoders: counts; setpoints: A or N·m; watchdog: ms)
  double bias = 0;
};

struct ModbusRegisterMap {
  RegisterField encoder_counts;             ///< per joint, read: counts = scale · raw + bias
  RegisterField setpoint;                   ///< per joint, holding, written: A or N·m (setpoint_kind)
  SetpointKind setpoint_kind = SetpointKind::kCurrent;
  std::optional<RegisterField> status;      ///< read; its bits' meaning in status_bits
  StatusBits status_bits;
  std::optional<RegisterField> buttons;     ///< read, the raw button word
  std::optional<RegisterField> enable;      ///< holding: enable_on while active, enable_off otherwise
  std::uint32_t enable_on = 1, enable_off = 0;
  std::optional<RegisterField> fault_reset; ///< holding: fault_reset_value written to clear a fault
  std::uint32_t fault_reset_value = 0;
  std::optional<RegisterField> heartbeat;   ///< holding, counts up by one on every write (wraps)
  std::optional<RegisterField> watchdog_timeout;  ///< holding, written at activation: drive_watchdog (ms) = scale · raw + bias
};

struct ModbusBusConfig {
  ModbusTransport transport = ModbusTransport::kTcp;
  std::string host;               ///< tcp
  int port = 502;                 ///< tcp, 1..65535
  std::string device;             ///< rtu, e.g. /dev/ttyUSB0
  int baud = 115200;              ///< rtu
  Parity parity = Parity::kNone;  ///< rtu
  int data_bits = 8;              ///< rtu, 7 or 8
  int stop_bits = 1;              ///< rtu, 1 or 2
  int unit_id = 1;                ///< 1..247
  double response_timeout = 0.005;  ///< s
  /// s: the drives' watchdog on the heartbeat register: they go torque-free and latch a fault
  /// when it stops changing this long while enabled (0: off; 0 too when the map has no heartbeat).
  double drive_watchdog = 0;
  ModbusRegisterMap registers;
};

enum class Cia402Mode : std::uint8_t {
  kCyclicSyncTorque,  ///< "cst", mode of operation 10
  kProfileTorque,     ///< "tq", mode of operation 4
};

/// One object mapped into a PDO.
struct PdoEntry {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  std::uint8_t bits = 0;  ///< 8, 16 or 32
};

/// A PDO, the same on every node; COB-ID from the predefined connection set (TPDOn: 0x80 + 0x100·n
/// + node, RPDOn: 0x100 + 0x100·n + node).
struct PdoConfig {
  int number = 1;        ///< 1..4
  int sync_divider = 1;  ///< sent every nth SYNC (CiA 301 transmission type n), 1..240
  std::vector<PdoEntry> entries;  ///< at most 64 bits in all
};

/// CiA 402 objects the driver uses (subindex 0); defaults are the profile's.
struct Cia402Objects {
  std::uint16_t controlword = 0x6040;
  std::uint16_t statusword = 0x6041;
  std::uint16_t position_actual = 0x6064;
  std::uint16_t target_torque = 0x6071;   ///< per mille of rated torque (0x6076)
  std::uint16_t digital_inputs = 0x60FD;
};

struct CanopenBusConfig {
  std::string interface_name;   ///< SocketCAN interface, e.g. can0
  int bitrate = 1'000'000;      ///< bit/s
  std::vector<int> node_ids;    ///< one per joint, 1..127, unique
  Cia402Mode mode = Cia402Mode::kCyclicSyncTorque;
  double sync_period = 0.001;   ///< s, a whole number of µs (0x1006); in cst mode one 0x60C2 can express
  double heartbeat_period = 0.1;  ///< s, consumer heartbeat expected from each node; 0: off
  int master_node_id = 127;     ///< this host's node id on the bus (its heartbeat: 0x700 + it), 1..127, not in node_ids
  /// s, the drive-side watchdog: each drive's heartbeat consumer time for the master (0x1016:1, whole
  /// ms); the master sends its heartbeat every drive_watchdog / 4. 0: off (no consumer, no heartbeat).
  double drive_watchdog = 0.1;
  Cia402Objects objects;
  std::vector<PdoConfig> rpdos;   ///< host → node
  std::vector<PdoConfig> tpdos;   ///< node → host
  std::optional<int> buttons_node;  ///< node whose digital inputs carry the buttons; unset: node_ids[0]
  /// true: this master sends the SYNC (one per read). false: another master on the same interface
  /// does (two arms on one bus: CiA 301 allows one SYNC producer), and a read takes this arm's
  /// nodes' TPDOs answering that SYNC. The master's own heartbeat goes out either way.
  bool sync_producer = true;
};

struct SafetyConfig {
  double max_force = 0;                  ///< N, at the tool point, > 0
  std::vector<double> max_joint_torque;  ///< N·m (N for prismatic joints), per joint, > 0
  double max_slew = 0;                   ///< N/s, >= 0; 0: no slew limit
  Vec3 workspace_min{}, workspace_max{}; ///< m, device frame, min < max on every axis
  double watchdog_period = 0;            ///< s, > 0
};

enum class ButtonAction : std::uint8_t { kNone, kClutch, kActivate, kMode };

struct ButtonConfig {
  std::string name;
  int bit = 0;              ///< bit in the backend's button word
  ButtonAction action = ButtonAction::kNone;
  bool active_low = false;
};

struct ArmConfig {
  std::string source;       ///< the file it came from
  int schema_version = 1;
  std::string name;
  std::string description;
  Backend backend = Backend::kSim;
  KinematicsConfig kinematics;
  std::vector<JointConfig> joints;        ///< one per joint, model order
  std::vector<ActuatorConfig> actuators;  ///< one per joint, model order
  // the bus section of the backend (only that one is set)
  std::optional<SimBusConfig> sim;
  std::optional<UsbBusConfig> usb;
  std::optional<ModbusBusConfig> modbus;
  std::optional<CanopenBusConfig> canopen;
  std::optional<FalconBusConfig> falcon;
  SafetyConfig safety;
  std::vector<ButtonConfig> buttons;

  [[nodiscard]] int joint_count() const noexcept { return kinematics.joint_count(); }
};

// ---------------------------------------------------------------------------------------------
// Loading and validation

/// One problem in a config file (file, line, column, field path, expected vs found, message).
using ConfigError = config::ConfigError;

struct ConfigReport {
  std::string file;
  bool readable = true;                 ///< false: the file could not be opened or read
  std::vector<ConfigError> errors;      ///< sorted by line, then column
  [[nodiscard]] bool ok() const noexcept { return readable && errors.empty(); }
};

/// Validates a config file; the report holds every error found (a TOML syntax error stops the
/// parse, so it is then the only one). Never throws (except std::bad_alloc).
ConfigReport validate_arm_config_file(const std::string& path);
/// As validate_arm_config_file, for text already in memory; `source_name` names it in errors.
ConfigReport validate_arm_config_text(std::string_view text, const std::string& source_name);

/// Loads and validates a config file. Errors: kNotFound / kSystem when it cannot be read,
/// kInvalid with the formatted report (every error, one per line) when it is not valid.
Result<ArmConfig> load_arm_config(const std::string& path);
/// As load_arm_config, for text already in memory.
Result<ArmConfig> load_arm_config_text(std::string_view text, const std::string& source_name);

/// The report as lines `file:line:col: field: message` (syntax errors have no field; an
/// unreadable file gives `file: message`), each ending in '\n'. Empty when there is no error.
std::string format_report(const ConfigReport& report);

// ---------------------------------------------------------------------------------------------
// Conversions between motor and joint space (the formulas in JointConfig). Real-time safe.

// ---- calibration: encoder offsets measured by `lancetctl calibrate`, kept next to the config ----
/// foo.toml → foo.calibration.toml (next to, never inside, the config).
[[nodiscard]] std::string calibration_path(const std::string& config_path);
/// The calibration file's text: each joint's offset (offset_deg or offset_mm, like the config) and
/// a comment saying when and from what it was measured.
[[nodiscard]] std::string calibration_text(const ArmConfig& config, std::span<const double> offsets, const std::string& note);
/// Replaces the joints' offsets with those in the calibration file at path. Returns false when
/// there is no such file (the config's own offsets stay); an error names file:line and field
/// (wrong arm name, joint count or names, unknown keys, non-numbers).
[[nodiscard]] Result<bool> apply_calibration_file(ArmConfig& config, const std::string& path);

/// Joint position (rad, or m for prismatic) for a raw encoder count.
[[nodiscard]] double joint_position_from_counts(const JointConfig& joint, std::int64_t counts) noexcept;
/// Motor current (A) that gives the joint torque tau (N·m, or N for prismatic) through the gear.
[[nodiscard]] double motor_current_for_joint_torque(const JointConfig& joint, const ActuatorConfig& actuator,
                                                    double tau) noexcept;

}  // namespace lancet::arm
