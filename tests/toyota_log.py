"""A realistic CAN log of a Toyota, made from comma.ai's public toyota_2017_pt.dbc (../shared), for
the tests that find a signal again in a log (``from toyota_log import toyota_drive`` in tests).

``toyota_drive()`` sends every message of the DBC at its cycle time (GenMsgCycleTime, else 100 ms
below id 0x400 and 1000 ms above) with a small jitter, for about a minute of driving: the speed
rises smoothly from standstill to about 30 m/s and falls back to 0; SPEED.SPEED, the wheel speeds
and the other speed fields carry it in km/h, steering and yaw follow a slow sine, counters roll,
checksums follow Toyota's rule and the rest hold plausible constants. The drive keeps the true
speed (m/s, 100 Hz) beside the frames; ``write_log`` and ``write_speed_csv`` write both out and
``dbc_without`` gives the DBC with one message taken out.

cantools (45) cannot encode or decode PCS_HUD, whose signals overlap (its bit layout comes out
longer than the frame): those frames are packed here bit by bit, as the DBC places the signals.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import can
import cantools
import numpy as np
import numpy.typing as npt

DBC_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "dbc"
TOYOTA_DBC = DBC_DIR / "toyota_2017_pt.dbc"
T0 = 1_700_000_000.0  # the absolute time of a drive's first frame (python-can's float seconds)
TRUTH_RATE = 100.0  # Hz: the true speed's samples
PEAK_MPS = 30.0  # the speed profile's top, about (a slow sine of ±3 m/s rides on it)
JITTER_S = 0.0003  # the standard deviation of a frame's time around its cycle
VIN = "JTDKARFU8H3000001"  # a made-up Prius VIN for VIN_PART_1..3
ODOMETER_KM = 23456.4  # at the start
ENCODER_PER_M = 2.0  # SPEED.ENCODER: a rolling 8-bit count of the wheels' pulses

FloatArray = npt.NDArray[np.float64]
Database = Any  # cantools.database.can.Database (load_file's declared type is a union)
Message = Any  # cantools.database.can.Message
Signal = Any  # cantools.database.can.Signal


def load_toyota(path: Path = TOYOTA_DBC) -> Database:
    """The DBC as cantools reads it leniently (strictly it refuses PCS_HUD's overlapping
    signals)."""
    return cantools.database.load_file(path, strict=False)


# ---------------------------------------------------------------------------------------------
# The DBC without one message


# Statements after the BO_ blocks that name a message by its id, and where the id stands.
_REFERS = (
    r'CM_\s+(?:BO_|SG_)\s+{id}\b',
    r'BA_\s+"[^"]*"\s+(?:BO_|SG_)\s+{id}\b',
    r'BA_REL_\s+"[^"]*"\s+BU_(?:SG|BO)_REL_\s+\w+\s+(?:SG_\s+)?{id}\b',
    r'(?:VAL_|SIG_VALTYPE_|SIG_GROUP_|BO_TX_BU_|SG_MUL_VAL_)\s+{id}\b',
)
_STATEMENTS = ("CM_", "BA_", "BA_REL_", "VAL_", "SIG_VALTYPE_", "SIG_GROUP_", "BO_TX_BU_",
               "SG_MUL_VAL_")


def _statement_complete(text: str) -> bool:
    """Whether a DBC statement (maybe several lines: a comment's string may hold line breaks)
    has ended: its quotes are closed and it ends with ';'."""
    quotes = text.count('"') - text.count('\\"')
    return quotes % 2 == 0 and text.rstrip().endswith(";")


def dbc_without(message: str, out: Path, *, source: Path = TOYOTA_DBC) -> Path:
    """Write ``source`` without the message named ``message``: its BO_ block and the CM_, BA_,
    VAL_ (...) statements that name its id. ``out`` is a folder (the file is then
    ``<stem>_without_<message>.dbc`` in it) or the file to write. Returns the file written."""
    db = load_toyota(source)
    m = db.get_message_by_name(message)  # KeyError for a message the DBC lacks
    dbc_id = m.frame_id | (0x80000000 if m.is_extended_frame else 0)
    target = out / f"{source.stem}_without_{message}.dbc" if out.is_dir() else out
    if target.resolve().is_relative_to(DBC_DIR.resolve()):
        raise ValueError(f"{target}: not writing beside the public DBCs in {DBC_DIR}")
    refers = re.compile("|".join(p.format(id=dbc_id) for p in _REFERS))
    block = re.compile(rf"BO_\s+{dbc_id}\s+\w+\s*:")

    # latin-1 turns every byte into one character and back: the copy keeps the source's bytes
    lines = source.read_bytes().decode("latin-1").splitlines(keepends=True)
    kept: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        if block.match(line):  # the message's block: its SG_ lines and the blank line after
            i += 1
            while i < len(lines) and lines[i].strip().startswith("SG_"):
                i += 1
            if i < len(lines) and not lines[i].strip():
                i += 1
            continue
        words = line.split(None, 1)  # (NS_'s indented list of keywords is no statement)
        if words and not line[0].isspace() and words[0] in _STATEMENTS:
            statement = [line]
            i += 1
            while not _statement_complete("".join(statement)) and i < len(lines):
                statement.append(lines[i])
                i += 1
            if not refers.match("".join(statement)):
                kept.extend(statement)
            continue
        kept.append(line)
        i += 1
    target.write_bytes("".join(kept).encode("latin-1"))

    written = load_toyota(target)
    if message in {x.name for x in written.messages}:
        raise AssertionError(f"{target} still defines {message}")
    return target


# ---------------------------------------------------------------------------------------------
# Counters, checksums and the frames' bit layout


def toyota_checksum(frame_id: int, data: bytes | bytearray) -> int:
    """Toyota's checksum of a frame (opendbc's toyota_checksum): the bytes of the id, the
    frame's length and every byte before the checksum (the last byte), summed, & 0xFF."""
    s = len(data)
    address = frame_id
    while address:
        s += address & 0xFF
        address >>= 8
    s += sum(data[:-1])
    return s & 0xFF


def checksum_signal(message: Message) -> Signal | None:
    """The message's checksum: an unsigned big-endian byte in the frame's last byte named
    CHECKSUM, or named like the leaked DBC's sums (VSC07SUM, VSCF02SM, SM228, ENG2F41S)."""
    for s in message.signals:
        if (s.length == 8 and s.byte_order == "big_endian" and not s.is_signed
                and s.start == 8 * message.length - 1
                and ("CHECKSUM" in s.name or re.search(r"(SUM|SM\d*|\dS)$", s.name))):
            return s
    return None


def is_counter(signal: Signal) -> bool:
    """A rolling counter: named so (COUNTER, ...CNT) or said to be one in its comment (RSA1's
    SYNCID1: "counter from 1 to f at 1 Hz"). The DBC has no signal named COUNTER."""
    return ("COUNTER" in signal.name or signal.name.endswith("CNT")
            or "counter" in (signal.comment or "").lower())


def counter_range(signal: Signal) -> tuple[int, int]:
    """The raw values a counter cycles through, first and last: "counter from 1 to f" in its
    comment, else every value of its bits."""
    found = re.search(r"counter from ([0-9a-f]+) to ([0-9a-f]+)", (signal.comment or "").lower())
    if found:
        return int(found[1], 16), int(found[2], 16)
    return 0, (1 << signal.length) - 1


def cycle_time(message: Message) -> float:
    """Seconds between a message's frames: its GenMsgCycleTime, else 0.1 s below id 0x400 and
    1 s above."""
    if message.cycle_time:
        return float(message.cycle_time) / 1000.0
    return 0.1 if message.frame_id < 0x400 else 1.0


def _bit_positions(signal: Signal) -> list[int]:
    """The frame bits (byte * 8 + bit, bit 0 the least significant) of a signal, from its most
    significant bit down."""
    if signal.byte_order == "little_endian":
        return [signal.start + i for i in range(signal.length)][::-1]
    positions = []
    pos = signal.start
    for _ in range(signal.length):
        positions.append(pos)
        pos = pos + 15 if pos % 8 == 0 else pos - 1
    return positions


def pack(message: Message, raw: dict[str, int]) -> bytes:
    """A frame of ``message`` carrying the raw values, placed bit by bit as the DBC says (signals
    that overlap are or-ed); the same bytes as cantools' encode where cantools can encode."""
    data = bytearray(message.length)
    for s in message.signals:
        value = raw.get(s.name, 0) & ((1 << s.length) - 1)  # two's complement for signed
        for i, pos in enumerate(_bit_positions(s)):
            if value >> (s.length - 1 - i) & 1:
                data[pos // 8] |= 1 << (pos % 8)
    return bytes(data)


def raw_limits(signal: Signal) -> tuple[int, int]:
    """The raw values a signal's bits can hold."""
    if signal.is_signed:
        return -(1 << (signal.length - 1)), (1 << (signal.length - 1)) - 1
    return 0, (1 << signal.length) - 1


def to_raw(signal: Signal, value: float) -> int:
    """A physical value as the signal's raw value, saturated at what its bits can hold."""
    lo, hi = raw_limits(signal)
    return min(hi, max(lo, round(float((value - signal.offset) / signal.scale))))


# ---------------------------------------------------------------------------------------------
# The car


def speed_profile(t: FloatArray | float, seconds: float) -> FloatArray:
    """The true speed (m/s) at ``t`` s into a drive of ``seconds``: an envelope that rises from 0
    and falls back to 0 (sin²), times PEAK_MPS - 3 m/s and a slow sine of ±3 m/s."""
    tt = np.asarray(t, dtype=np.float64)
    envelope = np.sin(np.pi * np.clip(tt / seconds, 0.0, 1.0)) ** 2
    return np.asarray(envelope * (PEAK_MPS - 3.0 + 3.0 * np.sin(2 * np.pi * tt / (seconds / 4.7))),
                      dtype=np.float64)


@dataclass(frozen=True)
class CarState:
    """The car at one instant, in physical units."""

    t: float  # s since the first frame
    time: float  # absolute seconds
    v: float  # m/s
    a: float  # m/s², along
    steer: float  # deg, the steering wheel
    steer_rate: float  # deg/s
    yaw_rate: float  # deg/s
    lateral: float  # m/s²
    distance_m: float  # since the first frame
    odometer_km: float
    lead_distance: float  # m
    lead_speed: float  # m/s, relative

    @property
    def kmh(self) -> float:
        return self.v * 3.6

    @property
    def braking(self) -> bool:
        return self.a < -0.8


def car_state(t: float, seconds: float, start: float, distance_m: float) -> CarState:
    """The car ``t`` s into the drive, ``distance_m`` from where it started."""
    h = 1e-3
    v = float(speed_profile(t, seconds))
    a = float(speed_profile(t + h, seconds) - speed_profile(t - h, seconds)) / (2 * h)
    w_steer = 2 * np.pi / 17.0
    steer = 8.0 * math.sin(w_steer * t)
    steer_rate = 8.0 * w_steer * math.cos(w_steer * t)
    yaw = v * math.tan(math.radians(steer / 15.4)) / 2.7  # rad/s: ratio 15.4, wheelbase 2.7 m
    w_lead = 2 * np.pi / 23.0
    return CarState(t=t, time=start + t, v=v, a=a, steer=steer, steer_rate=steer_rate,
                    yaw_rate=math.degrees(yaw), lateral=v * yaw, distance_m=distance_m,
                    odometer_km=ODOMETER_KM + distance_m / 1000.0,
                    lead_distance=35.0 + 8.0 * math.sin(w_lead * t),
                    lead_speed=8.0 * w_lead * math.cos(w_lead * t))


def _utc(s: CarState) -> dt.datetime:
    return dt.datetime.fromtimestamp(s.time, dt.timezone.utc)


def _gas(s: CarState) -> float:
    return min(1.0, max(0.0, 0.08 + 0.12 * s.a + 0.003 * s.v)) if s.a > -0.3 else 0.0


def _constant(value: float) -> Callable[[CarState], float]:
    return lambda s: value


def _drive_force(s: CarState) -> float:  # N: a 1500 kg car against its drag
    return 1500.0 * s.a + 0.4 * s.v ** 2


# Physical values that follow the drive, by "MESSAGE.SIGNAL" or by signal name.
DYNAMIC: dict[str, Callable[[CarState], float]] = {
    "SPEED.SPEED": lambda s: s.kmh,
    "SPEED.ENCODER": lambda s: math.floor(s.distance_m * ENCODER_PER_M) % 256,
    "WHEEL_SPEED_FL": lambda s: s.kmh * 1.002,
    "WHEEL_SPEED_FR": lambda s: s.kmh * 0.999,
    "WHEEL_SPEED_RL": lambda s: s.kmh * 1.001,
    "WHEEL_SPEED_RR": lambda s: s.kmh * 0.998,
    "FORWARD_SPEED": lambda s: s.kmh,  # saturates near 98 km/h (its bits)
    "UI_SPEED": lambda s: round(s.kmh),
    "KINEMATICS.ACCEL_X": lambda s: s.a,
    "KINEMATICS.ACCEL_Y": lambda s: s.lateral,
    "KINEMATICS.YAW_RATE": lambda s: s.yaw_rate,
    "GVC": lambda s: s.a,
    "GL1Z": lambda s: s.lateral,
    "GL2Z": lambda s: s.lateral,
    "ACCEL_NET": lambda s: s.a,
    "STEER_ANGLE": lambda s: s.steer,
    "STEER_FRACTION": lambda s: s.steer - 1.5 * round(s.steer / 1.5),
    "STEER_RATE": lambda s: s.steer_rate,
    "STEERING_IPAS.ANGLE": lambda s: s.steer,  # the measured angle while IPAS is inactive
    "STEER_TORQUE_DRIVER": lambda s: 3.0 * s.steer_rate,
    "STEER_TORQUE_EPS": lambda s: 2.0 * s.steer,
    "RPM": lambda s: 750.0 + 28.0 * s.kmh,
    "FDRV": _drive_force,
    "FDRVREAL": _drive_force,
    "GAS_PEDAL": _gas,
    "GAS_PEDAL_ALT": _gas,
    "BRAKE_PRESSED": lambda s: float(s.braking),
    "BRKON": lambda s: float(s.braking),
    "BRSTOP": lambda s: float(s.braking),
    "BRAKE_AMOUNT": lambda s: min(255.0, -40.0 * s.a) if s.braking else 0.0,
    "BRAKE_FORCE": lambda s: max(0.0, -_drive_force(s)) if s.braking else 0.0,
    "ODOMETER": lambda s: math.floor(s.odometer_km),
    "LEAD_LONG_DIST": lambda s: s.lead_distance,
    "LEAD_REL_SPEED": lambda s: s.lead_speed,
    "LUX_SENSOR": lambda s: 2000.0 + 300.0 * math.sin(2 * math.pi * s.t / 45.0),
    "YEAR": lambda s: _utc(s).year % 100,
    "MONTH": lambda s: _utc(s).month,
    "DAY": lambda s: _utc(s).day,
    "HOUR": lambda s: _utc(s).hour,
    "MINUTE": lambda s: _utc(s).minute,
    **{f"VIN_{i + 1}": _constant(ord(c)) for i, c in enumerate(VIN)},
}

# Physical values held all drive (the rest: 0, or the signal's minimum where 0 is out of range;
# SET_ME_Xnn: the raw value its name says).
CONSTANT: dict[str, float] = {
    "GEAR_PACKET_HYBRID.GEAR": 3,  # D
    "GEAR_PACKET.GEAR": 0,  # D
    "DRIVE_ENGAGED": 1,
    "ENGINE_RUNNING": 1,
    "CRUISE_CONTROL_STATE": 2,  # disabled
    "LOW_SPEED_LOCKOUT": 1,  # ok
    "PCM_FOLLOW_DISTANCE": 2,  # medium
    "ACC_TYPE": 1,  # ok
    "PERMIT_BRAKING": 1,
    "CLIMATE_SET_POINT": 22,
    "AIR_CONDITIONER_STATE": 20,
    "METER_SLIDER_BRIGHTNESS_PCT": 100,
    "BODY_CONTROL_STATE_2.UNITS": 1,  # km (km/L)
    "UI_SETTING.UNITS": 1,  # km
    "TURN_SIGNALS": 3,  # none
    "REVERSE_CAMERA_GUIDELINES": 3,  # no guidelines
    "HEADLIGHT_MODE": 7,  # auto low beams
    "DAYTIME_RUNNING_LIGHT": 1,
    "VSC1S29.LOCK_STATUS": 1,
    "CLUTCH_RELEASED": 1,
    "STEERING_IPAS.STATE": 1,  # disabled
    "DIRECTION_CMD": 2,  # center
    "LDA_SA_TOGGLE": 1,
    "LDA_SENSITIVITY": 2,  # standard
    "LKAS_STATUS": 1,
    "TSREQPD": 1,  # the comments of RSA3: "always 1", "always 3", ...
    "TSRMSW": 1,
    "OTSGNNTM": 3,
    "NTLVLSPD": 3,
    "OVSPNTM": 3,
    "OVSPVALL": 2,
    "OVSPVALM": 5,
    "OVSPVALH": 10,
    "TSRSPU": 1,
    "SPDVAL1": 255,  # no limit
}

# Noise on a signal's raw value: (standard deviation, bound), in raw units.
RAW_NOISE: dict[str, tuple[float, int]] = {
    "SPEED.SPEED": (0.4, 1),  # 0.01 km/h a step: mostly exact, now and then ±0.01 km/h
    "WHEEL_SPEED_FL": (1.0, 3),
    "WHEEL_SPEED_FR": (1.0, 3),
    "WHEEL_SPEED_RL": (1.0, 3),
    "WHEEL_SPEED_RR": (1.0, 3),
}


def _lookup(table: dict[str, Any], message: Message, signal: Signal) -> Any:
    return table.get(f"{message.name}.{signal.name}", table.get(signal.name))


def constant_raw(message: Message, signal: Signal) -> int:
    """The raw value a signal holds when nothing drives it."""
    set_me = re.fullmatch(r"SET_ME_X([0-9A-F]+)(?:_\d+)?", signal.name)
    if set_me:
        return min(raw_limits(signal)[1], int(set_me[1], 16))
    value = _lookup(CONSTANT, message, signal)
    if value is None:
        lo, hi = signal.minimum, signal.maximum
        ranged = lo is not None and hi is not None and (lo, hi) != (0, 0)
        value = lo if ranged and not lo <= 0 <= hi else 0.0
    return to_raw(signal, float(value))


class _Sender:
    """One message's frames: its values for a car state, its counters rolling, its checksum."""

    def __init__(self, message: Message, rng: np.random.Generator) -> None:
        self.message = message
        self.rng = rng
        self.checksum = checksum_signal(message)
        self.counters = {s.name: counter_range(s) for s in message.signals if is_counter(s)}
        self.count = {name: int(rng.integers(lo, hi + 1))
                      for name, (lo, hi) in self.counters.items()}
        self.dynamic = {s.name: f for s in message.signals
                        if (f := _lookup(DYNAMIC, message, s)) is not None}
        self.noise = {s.name: n for s in message.signals
                      if (n := _lookup(RAW_NOISE, message, s)) is not None}
        self.signals = {s.name: s for s in message.signals}
        self.base = {s.name: constant_raw(message, s) for s in message.signals}
        self.use_cantools = _cantools_encodes(message)

    def frame(self, state: CarState) -> bytes:
        raw = dict(self.base)
        for name, f in self.dynamic.items():
            signal = self.signals[name]
            value = to_raw(signal, f(state))
            if name in self.noise:
                sigma, bound = self.noise[name]
                value += max(-bound, min(bound, round(float(self.rng.normal(0.0, sigma)))))
                lo, hi = raw_limits(signal)
                value = min(hi, max(lo, value))
            raw[name] = value
        for name, (lo, hi) in self.counters.items():
            raw[name] = self.count[name]
            self.count[name] = lo if self.count[name] >= hi else self.count[name] + 1
        if self.checksum is not None:
            raw[self.checksum.name] = 0
        if self.use_cantools:
            data = bytearray(self.message.encode(raw, scaling=False, strict=False))
        else:
            data = bytearray(pack(self.message, raw))
        if self.checksum is not None:
            data[self.checksum.start // 8] = toyota_checksum(self.message.frame_id, data)
        return bytes(data)


def _cantools_encodes(message: Message) -> bool:
    """Whether cantools encodes the message (not PCS_HUD: its overlapping signals)."""
    try:
        message.encode({s.name: 1 for s in message.signals}, scaling=False, strict=False)
    except (OverflowError, ValueError, cantools.database.errors.Error):
        return False
    return True


# ---------------------------------------------------------------------------------------------
# The drive


class ToyotaDrive(NamedTuple):
    """A drive: the frames (python-can messages, channel 0, absolute float seconds) and the true
    speed at TRUTH_RATE: ``t`` seconds since the first frame, ``speed_mps``."""

    frames: list[can.Message]
    t: FloatArray
    speed_mps: FloatArray
    start: float  # the first frame's timestamp

    @property
    def speed_kmh(self) -> FloatArray:
        return self.speed_mps * 3.6

    @property
    def log_t(self) -> FloatArray:
        """The truth's times on the log's own clock (the frames' absolute seconds)."""
        return self.t + self.start

    def truth_at(self, t: Sequence[float] | FloatArray) -> FloatArray:
        """The true speed (m/s) at times since the first frame, interpolated."""
        return np.interp(np.asarray(t, dtype=np.float64), self.t, self.speed_mps)


def toyota_drive(seconds: float = 60.0, seed: int = 0, *, start: float = T0,
                 dbc: Path = TOYOTA_DBC) -> ToyotaDrive:
    """About ``seconds`` of a Toyota on one bus: every message of the DBC at its cycle time with a
    small jitter (each from its own phase), the first frame at ``start``. The same seed gives the
    same drive."""
    rng = np.random.default_rng(seed)
    db = load_toyota(dbc)
    schedule: list[tuple[float, int, Message]] = []
    for m in sorted(db.messages, key=lambda m: m.frame_id):
        cycle = cycle_time(m)
        phase = float(rng.uniform(0.0, cycle))
        n = max(1, math.ceil((seconds - phase) / cycle))
        jitter = np.clip(rng.normal(0.0, JITTER_S, n), -3 * JITTER_S, 3 * JITTER_S)
        schedule.extend((phase + k * cycle + float(jitter[k]), m.frame_id, m) for k in range(n))
    schedule.sort(key=lambda x: (x[0], x[1]))
    first = schedule[0][0]

    t = np.arange(round(seconds * TRUTH_RATE) + 1, dtype=np.float64) / TRUTH_RATE
    speed = speed_profile(t, seconds)
    distance = np.concatenate(([0.0], np.cumsum((speed[1:] + speed[:-1]) / 2) / TRUTH_RATE))

    senders = {m.frame_id: _Sender(m, rng) for m in db.messages}
    frames = []
    for when, frame_id, m in schedule:
        rel = when - first
        state = car_state(rel, seconds, start, float(np.interp(rel, t, distance)))
        data = senders[frame_id].frame(state)
        frames.append(can.Message(timestamp=start + rel, arbitration_id=frame_id,
                                  is_extended_id=m.is_extended_frame, data=data, dlc=len(data),
                                  channel=0))
    return ToyotaDrive(frames=frames, t=t, speed_mps=speed, start=start)


def write_log(drive: ToyotaDrive, path: Path) -> Path:
    """Write the drive's frames with python-can's writer for the file's suffix (.blf, .log
    candump, .asc, .csv, .trc, ...). Returns ``path``."""
    with can.Logger(path) as logger:
        for m in drive.frames:
            logger.on_message_received(m)
    return path


def write_speed_csv(drive: ToyotaDrive, path: Path, *, clock: str = "source") -> Path:
    """The true speed as CSV: ``time,speed_mps``, one row per sample; ``clock`` "source" gives
    seconds since the log's first frame, "log" the log's own absolute seconds. Returns ``path``."""
    if clock == "source":
        times = drive.t
    elif clock == "log":
        times = drive.log_t
    else:
        raise ValueError(f"clock {clock!r}: expected 'source' or 'log'")
    rows = "".join(f"{t:.6f},{v:.6f}\n" for t, v in zip(times, drive.speed_mps, strict=True))
    path.write_text("time,speed_mps\n" + rows, encoding="utf-8")
    return path
