#pragma once
// Object dictionary indexes of CiA 301 (communication profile) and CiA 402 (drive profile) that
// the driver and the emulated drives both use. An arm config may place the cyclic objects
// elsewhere ([bus.canopen.objects]); these are the profiles' own indexes.

#include <cstdint>

namespace lancet::device::canopen::od {

// CiA 301
inline constexpr std::uint16_t kDeviceType = 0x1000;         ///< low 16 bits: the device profile
inline constexpr std::uint16_t kErrorRegister = 0x1001;
inline constexpr std::uint16_t kCommunicationCyclePeriod = 0x1006;  ///< µs
inline constexpr std::uint16_t kConsumerHeartbeatTime = 0x1016;     ///< sub n: consumer entry n
inline constexpr std::uint16_t kProducerHeartbeatTime = 0x1017;     ///< ms, 0: off
inline constexpr std::uint16_t kIdentity = 0x1018;           ///< sub 1 vendor id, 2 product, 3 revision, 4 serial
inline constexpr std::uint32_t kProfileCia402 = 402;         ///< the device type's low 16 bits for a drive

// CiA 402
inline constexpr std::uint16_t kAbortConnectionOption = 0x6007;
inline constexpr std::uint16_t kControlword = 0x6040;
inline constexpr std::uint16_t kStatusword = 0x6041;
inline constexpr std::uint16_t kModesOfOperation = 0x6060;
inline constexpr std::uint16_t kModesOfOperationDisplay = 0x6061;
inline constexpr std::uint16_t kPositionActual = 0x6064;
inline constexpr std::uint16_t kTargetTorque = 0x6071;       ///< ‰ of the rated torque
inline constexpr std::uint16_t kMaxTorque = 0x6072;          ///< ‰ of the rated torque
inline constexpr std::uint16_t kMotorRatedTorque = 0x6076;   ///< mN·m
inline constexpr std::uint16_t kTorqueActual = 0x6077;       ///< ‰ of the rated torque
inline constexpr std::uint16_t kInterpolationTimePeriod = 0x60C2;  ///< sub 1 value, sub 2 index
inline constexpr std::uint16_t kDigitalInputs = 0x60FD;
inline constexpr std::uint16_t kSupportedDriveModes = 0x6502;

}  // namespace lancet::device::canopen::od
