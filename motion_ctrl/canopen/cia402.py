"""The CiA 402 drive profile (IEC 61800-7-201), what of it a torque-mode servo needs: the objects,
the controlword commands, the statusword's states and the power drive system's state machine.

The state machine (CiA 402 figure "state machine of the drive", transitions 0-16):

    NOT READY TO SWITCH ON --1--> SWITCH ON DISABLED --2 shutdown--> READY TO SWITCH ON
    READY TO SWITCH ON --3 switch on--> SWITCHED ON --4 enable operation--> OPERATION ENABLED
    OPERATION ENABLED --5 disable operation--> SWITCHED ON --6 shutdown--> READY TO SWITCH ON
    OPERATION ENABLED --8 shutdown--> READY TO SWITCH ON
    READY / SWITCHED ON / OPERATION ENABLED --7, 10, 9 disable voltage--> SWITCH ON DISABLED
    OPERATION ENABLED --11 quick stop--> QUICK STOP ACTIVE --12 (done, or disable voltage)-->
        SWITCH ON DISABLED;  QUICK STOP ACTIVE --16 enable operation--> OPERATION ENABLED
        (quick stop option codes 5-8 only)
    any --13 fault--> FAULT REACTION ACTIVE --14 (reaction done)--> FAULT
    FAULT --15 fault reset (controlword bit 7 rising)--> SWITCH ON DISABLED

`DriveStateMachine` is the drive's side (the emulated drive runs it); `master_controlword` is the
master's: the next controlword that walks a drive from the state it reports towards OPERATION
ENABLED (enable: shutdown, switch on, enable operation) or SWITCH ON DISABLED (disable voltage).
"""
from __future__ import annotations

# -- objects (CiA 301 communication area, CiA 402 / CiA 406 device profile area) -------------------
DEVICE_TYPE = 0x1000            # low 16 bits: the device profile (402 drive, 406 encoder)
ERROR_REGISTER = 0x1001
COB_ID_SYNC = 0x1005
CYCLE_PERIOD = 0x1006           # communication cycle period [us]: the SYNC interval
COB_ID_EMCY = 0x1014
CONSUMER_HEARTBEAT = 0x1016
PRODUCER_HEARTBEAT = 0x1017     # [ms]
IDENTITY = 0x1018
RPDO_COMM, RPDO_MAP = 0x1400, 0x1600
TPDO_COMM, TPDO_MAP = 0x1800, 0x1A00
ERROR_CODE = 0x603F             # the drive's last fault (same codes as EMCY)
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
QUICK_STOP_OPTION = 0x605A
FAULT_REACTION_OPTION = 0x605E
MODES_OF_OPERATION = 0x6060
MODES_DISPLAY = 0x6061
POSITION_ACTUAL = 0x6064        # the motor encoder [counts]
VELOCITY_ACTUAL = 0x606C
TARGET_TORQUE = 0x6071          # per mille of the rated torque
MAX_TORQUE = 0x6072             # per mille of the rated torque
RATED_TORQUE = 0x6076           # [mN·m]
TORQUE_ACTUAL = 0x6077          # per mille of the rated torque
QUICK_STOP_DECELERATION = 0x6085    # [counts/s²] of the position actual value
ADDITIONAL_POSITION = 0x60E4    # sub 1: a second encoder (the load) [counts]
SUPPORTED_MODES = 0x6502
ENCODER_POSITION = 0x6004       # CiA 406: position value [counts]

PROFILE_DRIVE = 402
PROFILE_ENCODER = 406

# 6060h / 6061h modes of operation, and their bits in 6502h
CST = 10
MODES = {1: 'profile position', 3: 'profile velocity', 4: 'profile torque', 6: 'homing',
         7: 'interpolated position', 8: 'cyclic synchronous position',
         9: 'cyclic synchronous velocity', 10: 'cyclic synchronous torque'}
SUPPORTED_MODE_BIT = {1: 0, 3: 2, 4: 3, 6: 5, 7: 6, 8: 7, 9: 8, 10: 9}

# -- controlword commands (bits 7 fault reset, 3 enable operation, 2 quick stop, 1 enable
#    voltage, 0 switch on) -----------------------------------------------------------------------
CW_DISABLE_VOLTAGE = 0x00
CW_QUICK_STOP = 0x02
CW_SHUTDOWN = 0x06
CW_SWITCH_ON = 0x07             # also "disable operation"
CW_ENABLE_OPERATION = 0x0F      # also "switch on + enable operation"
CW_FAULT_RESET = 0x80

# -- states, and the statusword bits that tell them ---------------------------------------------
NOT_READY = 'NOT READY TO SWITCH ON'
SWITCH_ON_DISABLED = 'SWITCH ON DISABLED'
READY = 'READY TO SWITCH ON'
SWITCHED_ON = 'SWITCHED ON'
OPERATION_ENABLED = 'OPERATION ENABLED'
QUICK_STOP_ACTIVE = 'QUICK STOP ACTIVE'
FAULT_REACTION = 'FAULT REACTION ACTIVE'
FAULT = 'FAULT'

# (mask, value, state) in the order CiA 402 table "state coding" gives them
_CODING = ((0x4F, 0x00, NOT_READY), (0x4F, 0x40, SWITCH_ON_DISABLED), (0x6F, 0x21, READY),
           (0x6F, 0x23, SWITCHED_ON), (0x6F, 0x27, OPERATION_ENABLED),
           (0x6F, 0x07, QUICK_STOP_ACTIVE), (0x4F, 0x0F, FAULT_REACTION), (0x4F, 0x08, FAULT))
_STATUS_BITS = {NOT_READY: 0x00, SWITCH_ON_DISABLED: 0x40, READY: 0x21, SWITCHED_ON: 0x23,
                OPERATION_ENABLED: 0x27, QUICK_STOP_ACTIVE: 0x07, FAULT_REACTION: 0x0F,
                FAULT: 0x08}
SW_VOLTAGE_ENABLED = 0x10
SW_WARNING = 0x80
SW_REMOTE = 0x200               # the drive takes its commands from the bus
SW_TARGET_REACHED = 0x400


def state_of(statusword: int) -> str:
    """The state a statusword reports ('UNKNOWN 0x....' for a coding CiA 402 does not have)."""
    for mask, value, state in _CODING:
        if statusword & mask == value:
            return state
    return f'UNKNOWN 0x{statusword:04X}'


def is_fault(statusword: int) -> bool:
    """Bit 3: FAULT or FAULT REACTION ACTIVE."""
    return bool(statusword & 0x08)


def command_of(controlword: int) -> str:
    """The device control command a controlword carries (bit 7 aside: a fault reset is its
    rising edge, which the state machine sees)."""
    if not controlword & 0x02:
        return 'disable voltage'
    if not controlword & 0x04:
        return 'quick stop'
    if not controlword & 0x01:
        return 'shutdown'
    if not controlword & 0x08:
        return 'switch on'          # or disable operation, from OPERATION ENABLED
    return 'enable operation'


def master_controlword(state: str, enable: bool) -> int:
    """The controlword that moves a drive reporting `state` one transition towards OPERATION
    ENABLED (`enable`) or SWITCH ON DISABLED. A drive in FAULT needs a fault reset first
    (`DriveStateMachine` resets on bit 7's rising edge: the master sends 0 before it)."""
    if not enable:
        return CW_DISABLE_VOLTAGE
    if state in (SWITCH_ON_DISABLED, NOT_READY):
        return CW_SHUTDOWN                              # 2
    if state == READY:
        return CW_SWITCH_ON                             # 3
    return CW_ENABLE_OPERATION                          # 4 (and held in OPERATION ENABLED)


class DriveStateMachine:
    """The drive's side of the state machine: fed every controlword the drive applies (each SYNC)
    and the drive's own events (a fault, the end of a quick stop); `statusword` says the state.

    `quick_stop_option` is 605Ah: 1-4 end a quick stop in SWITCH ON DISABLED, 5-8 stay in
    QUICK STOP ACTIVE until enable operation (or disable voltage); 0 disables the drive at once.
    """

    def __init__(self, quick_stop_option: int = 2) -> None:
        self.state = SWITCH_ON_DISABLED                 # transitions 0 and 1 at power-on
        self.quick_stop_option = quick_stop_option
        self.error_code = 0
        self._last_cw = 0

    @property
    def statusword(self) -> int:
        return _STATUS_BITS[self.state] | SW_REMOTE | (
            SW_VOLTAGE_ENABLED if self.state in (READY, SWITCHED_ON, OPERATION_ENABLED,
                                                 QUICK_STOP_ACTIVE) else 0)

    @property
    def enabled(self) -> bool:
        """The power stage follows the target torque (OPERATION ENABLED)."""
        return self.state == OPERATION_ENABLED

    def controlword(self, cw: int) -> str:
        """Apply a controlword; returns the state after it."""
        rising_reset = bool(cw & CW_FAULT_RESET and not self._last_cw & CW_FAULT_RESET)
        self._last_cw = cw
        s = self.state
        if s == FAULT:
            if rising_reset:
                self.state = SWITCH_ON_DISABLED         # 15
                self.error_code = 0
            return self.state
        if s == FAULT_REACTION or cw & CW_FAULT_RESET:
            return s                                    # a reset is no command elsewhere
        command = command_of(cw)
        if command == 'disable voltage':
            if s in (READY, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE):
                self.state = SWITCH_ON_DISABLED         # 7, 10, 9, 12
        elif command == 'quick stop':
            if s in (READY, SWITCHED_ON):
                self.state = SWITCH_ON_DISABLED         # 7, 10
            elif s == OPERATION_ENABLED:
                self.state = (QUICK_STOP_ACTIVE if self.quick_stop_option
                              else SWITCH_ON_DISABLED)  # 11 (option 0: disable at once)
        elif command == 'shutdown':
            if s in (SWITCH_ON_DISABLED, SWITCHED_ON, OPERATION_ENABLED):
                self.state = READY                      # 2, 6, 8
        elif command == 'switch on':
            if s == READY:
                self.state = SWITCHED_ON                # 3
            elif s == OPERATION_ENABLED:
                self.state = SWITCHED_ON                # 5
        elif command == 'enable operation':
            if s == READY:
                self.state = OPERATION_ENABLED          # 3 + 4 (CiA 402 allows both at once)
            elif s == SWITCHED_ON:
                self.state = OPERATION_ENABLED          # 4
            elif s == QUICK_STOP_ACTIVE and self.quick_stop_option >= 5:
                self.state = OPERATION_ENABLED          # 16
        return self.state

    def fault(self, code: int) -> None:
        """The drive detected a fault (603Fh = code): the fault reaction starts (13)."""
        if self.state not in (FAULT_REACTION, FAULT):
            self.state = FAULT_REACTION
            self.error_code = code

    def fault_reaction_done(self) -> None:
        """The fault reaction ended (14)."""
        if self.state == FAULT_REACTION:
            self.state = FAULT

    def quick_stop_done(self) -> None:
        """The quick stop ramp reached standstill (12 for options 1-4)."""
        if self.state == QUICK_STOP_ACTIVE and self.quick_stop_option < 5:
            self.state = SWITCH_ON_DISABLED
