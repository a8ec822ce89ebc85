"""What the two device profiles mean on this stand: object indexes, states, scaling, EMCY codes.

Shared by the gateway (master) and the emulator (slaves), so both sides read the same numbers.
Facts: CiA 301 (communication), CiA 408 (servo-valve drive), CiA 404 (dynamometer); see
``../shared/notes/canopen.md``.
"""
from __future__ import annotations

import enum
import math

# -- default node ids --------------------------------------------------------------------------
VALVE_NODE_ID = 1
DYNAMOMETER_NODE_ID = 2

# -- CiA 301 communication objects -------------------------------------------------------------
SYNC_COB_ID = 0x080               # the SYNC's default COB-ID; DLC 0 (no counter) or 1 (counter)

# -- CiA 301 predefined connection set: COB-ID = base + node id ----------------------------------
NMT_COB_ID = 0x000                # NMT command: (command, node id)
EMCY_BASE = 0x080
TPDO_BASES = (0x180, 0x280, 0x380, 0x480)
RPDO_BASES = (0x200, 0x300, 0x400, 0x500)
SDO_TX_BASE = 0x580               # server → client
SDO_RX_BASE = 0x600               # client → server
HEARTBEAT_BASE = 0x700            # heartbeat and boot-up

# -- NMT commands and the states heartbeats report ---------------------------------------------
NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82
NMT_STATE_NAMES = {0: "BOOT-UP", 4: "STOPPED", 5: "OPERATIONAL", 127: "PRE-OPERATIONAL"}
DEVICE_TYPE = 0x1000
ERROR_REGISTER = 0x1001
COMM_CYCLE_PERIOD = 0x1006        # µs; in lockstep the emulator advances this much per SYNC
SYNC_WINDOW = 0x1007              # µs; a synchronous TPDO not sent this soon after its SYNC is
                                  # discarded (CiA 301; 0: no window)
PRODUCER_HEARTBEAT = 0x1017       # ms
IDENTITY = 0x1018                 # sub 1 vendor, 2 product, 3 revision, 4 serial
SYNC_COUNTER_OVERFLOW = 240       # our SYNC counter runs 1..240 (0x1019 on the producer)
EMULATOR_CLOCK = 0x2100           # manufacturer object of the emulated valve: 0 real time, 1 lockstep

# -- CiA 408 servo-valve drive -------------------------------------------------------------------
CONTROL_WORD = 0x6040
STATUS_WORD = 0x6041
DEVICE_MODE = 0x6042              # 1 = setpoint via bus
CONTROL_MODE = 0x6043             # 1 = spool position open loop
SETPOINT = (0x6300, 1)
ACTUAL_VALUE = (0x6301, 1)
HOLD_SETPOINT = 0x6314
UPPER_LIMIT = 0x6320
LOWER_LIMIT = 0x6321

#: setpoint counts per percent: 16384 counts = 100 % = 10 V
COUNTS_PER_PERCENT = 163.84
PERCENT_PER_COUNT = 100.0 / 16384  # exact in binary: 0.006103515625


class ControlBit(enum.IntFlag):
    """CiA 408 control word 0x6040, bits 0-3."""

    DISABLE = 0x1      #: leave INIT/enter DISABLED (spool to its fail-safe position)
    HOLD = 0x2         #: HOLD: spool to the hold setpoint 0x6314
    ACTIVE = 0x4       #: device mode active: follow the bus setpoint
    RESET_FAULT = 0x8  #: rising edge resets a fault state


#: control words the gateway sends
CW_DISABLED = ControlBit.DISABLE
CW_HOLD = ControlBit.DISABLE | ControlBit.HOLD
CW_ACTIVE = ControlBit.DISABLE | ControlBit.HOLD | ControlBit.ACTIVE


class ValveState(enum.IntEnum):
    """CiA 408 device state, as bits 0-3 of the status word 0x6041.

    Bits 0-2 mirror the control bits (D, H, M); bit 3 is set while no fault is present.
    """

    INIT = 0b1000
    DISABLED = 0b1001
    HOLD = 0b1011
    ACTIVE = 0b1111
    FAULT_DISABLED = 0b0001
    FAULT_HOLD = 0b0011
    FAULT_REACTION = 0b0111

    @classmethod
    def from_status(cls, status_word: int) -> "ValveState | None":
        try:
            return cls(status_word & 0xF)
        except ValueError:
            return None

    @property
    def is_fault(self) -> bool:
        return not (self.value & 0b1000)


STATUS_LIMIT_REACHED = 1 << 10
STATUS_CONTROL_DEVIATION = 1 << 11


def percent_to_counts(u_percent: float) -> int:
    """Valve command in % → setpoint counts (INT16), rounded and clipped to ±16384 (±100 %).

    NaN or infinite input gives 0 (no flow): never a wild command."""
    if not math.isfinite(u_percent):
        return 0
    return int(max(-16384, min(16384, round(u_percent * COUNTS_PER_PERCENT))))


def counts_to_percent(counts: int) -> float:
    return counts * PERCENT_PER_COUNT


# -- CiA 404 dynamometer -------------------------------------------------------------------------
PV_INT32 = (0x9130, 1)
PV_REAL32 = (0x6130, 1)
PV_UNIT = (0x6131, 1)              # CiA 303-2: unit code in byte 2, prefix in byte 3
PV_DECIMALS = (0x6132, 1)
AI_STATUS = (0x6150, 1)
AI_STATUS_INVALID = 0x1
AI_STATUS_POSITIVE_OVERLOAD = 0x2
AI_STATUS_NEGATIVE_OVERLOAD = 0x4

N_PER_KGF = 9.80665
UNIT_NEWTON = 0x21
_PREFIX = {0x00: 1.0, 0x03: 1e3, 0xFD: 1e-3, 0x06: 1e6}  # CiA 303-2 prefix byte (two's complement exponent)
UNIT_N_DEFAULT = UNIT_NEWTON << 16


def force_scale_kgf(unit_code: int, decimals: int) -> float:
    """kgf per process-value count, from 0x6131 (unit) and 0x6132 (decimal digits).

    Raises ValueError for units that are not a force (kgf has no CiA 303-2 code; a transducer
    reports newtons, possibly with a prefix)."""
    unit = (unit_code >> 16) & 0xFF
    prefix = (unit_code >> 24) & 0xFF
    if unit != UNIT_NEWTON or prefix not in _PREFIX:
        raise ValueError(
            f"dynamometer reports unit code 0x{unit_code:08X}, not newtons (0x{UNIT_N_DEFAULT:08X}); "
            "configure the transducer for N or kN")
    if not 0 <= decimals <= 9:
        raise ValueError(f"dynamometer decimal digits {decimals} out of range 0..9")
    return _PREFIX[prefix] * 10.0 ** -decimals / N_PER_KGF


# -- EMCY error codes (CiA 301 generic; 0xFFxx device specific) ------------------------------------
EMCY_NO_ERROR = 0x0000
EMCY_PDO_LENGTH = 0x8210          # CiA 301: PDO not processed due to length error
EMCY_RPDO_TIMEOUT = 0x8250        # CiA 301: RPDO timeout
EMCY_HEARTBEAT = 0x8130           # CiA 301: life guard / heartbeat error
EMCY_FORCE_OVER_RANGE = 0xFF10    # dynamometer: force beyond the measuring range
EMCY_VALVE_FAULT = 0xFF20         # valve: device fault reaction


def emcy_text(code: int) -> str:
    return {
        EMCY_NO_ERROR: "error reset / no error",
        EMCY_PDO_LENGTH: "PDO not processed: wrong length",
        EMCY_RPDO_TIMEOUT: "RPDO timeout (no command received in time)",
        EMCY_HEARTBEAT: "heartbeat error",
        EMCY_FORCE_OVER_RANGE: "force beyond the measuring range",
        EMCY_VALVE_FAULT: "valve fault reaction",
    }.get(code, f"error code 0x{code:04X}")
