#pragma once
// The CANopen codec: CiA 301 (COB-IDs, NMT and heartbeat, SDO, EMCY, PDO parameters) and CiA 402
// (drive states, modes, torque units), shared by the driver (device/canopen_arm.hpp) and the
// emulated drives (armsim/canopen_nodes.hpp). No socket, no clock: frames in, frames out.

#include "device/canopen/cia402.hpp"
#include "device/canopen/cob_id.hpp"
#include "device/canopen/emcy.hpp"
#include "device/canopen/frame.hpp"
#include "device/canopen/nmt.hpp"
#include "device/canopen/objects.hpp"
#include "device/canopen/pdo.hpp"
#include "device/canopen/sdo.hpp"
#include "device/canopen/torque_units.hpp"
