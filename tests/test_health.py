"""Health: the monitor names each simulated fault within two seconds of log time, clears it after
recovery, and stays quiet on a clean drive; bus load comes from bit-exact frame lengths.

Every drive goes through the loop the pipeline runs: before each frame the scene ticks that are
due (their world goes to the monitor's object checks) and the monitor's own checks, then the
frame is decoded, observed and counted. What the monitor never sees is left out: a scene tick
brings the world up to date but builds no scene or semantic message, and the ecocar databases and
profile are loaded once (each drive gets a decoder of its own).
"""

from __future__ import annotations

import dataclasses
import functools
import random
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.decode.codec import Decoded
from bridge.decode.database import DatabaseFile
from bridge.decode.decoder import Decoder
from bridge.errors import UsageError
from bridge.frame import NS, Frame
from bridge.health import alarms
from bridge.health.alarms import AlarmInfo, AlarmKind, HealthSettings, alarm_id, alarm_notice
from bridge.health.bus_bits import estimate_frame_bits, frame_bits
from bridge.health.monitor import HealthMonitor
from bridge.health.overlay import alarm_entities, fov_entities
from bridge.pb.health_pb2 import Health
from bridge.pipeline.drive import load_stages
from bridge.pipeline.perception import Perception
from bridge.profile.model import Profile
from bridge.resources import data_dir
from bridge.sim.ecocar import simulate
from bridge.sim.frames import load_ecocar
from bridge.sim.scenario import DEFAULT_START_NS, FAULT_ONSET_S, FAULT_RECOVERY_S, SCENARIOS
from bridge.topics import HEALTH_TOPIC, LOG_TOPIC, TopicMessage

BITRATE = 1_000_000
DATA_BITRATE = 2_000_000
SETTINGS = HealthSettings()


@dataclass
class Drive:
    monitor: HealthMonitor
    outputs: list[TopicMessage]

    def events(self) -> list[tuple[str, str, float]]:
        """(alarm id, "raised" or "cleared", seconds since the start of the drive)."""
        return [(alarm, event, (t - DEFAULT_START_NS) / NS)
                for alarm, event, t, _ in self.monitor.events]

    def health(self) -> list[tuple[float, Health]]:
        return [((o.t_ns - DEFAULT_START_NS) / NS, o.message) for o in self.outputs
                if o.topic == HEALTH_TOPIC]

    def health_at(self, seconds: float) -> Health:
        return next(h for t, h in self.health() if t >= seconds)


class HealthPerception(Perception):
    """The perception stage as far as the health checks look: each scene tick brings the world up
    to the tick as :meth:`Perception.tick` does (:meth:`Perception.update_world`) and hands it
    to the monitor as the pipeline does, but builds none of the scene and semantic messages,
    which the monitor never sees (they were half the time of a tick)."""

    def __init__(self, profile: Profile, monitor: HealthMonitor) -> None:
        super().__init__(profile)
        self.monitor = monitor

    def tick(self, t_ns: int) -> list[TopicMessage]:
        self.monitor.on_world(t_ns, self.world, self.update_world(t_ns))
        return []


def run(frames: Iterable[Frame], decoder: Decoder, profile: Profile | None, *,
        bitrates: dict[str, int] | None = None,
        data_bitrates: dict[str, int] | None = None) -> Drive:
    monitor = HealthMonitor(profile, decoder, bitrates=bitrates, data_bitrates=data_bitrates)
    perception = HealthPerception(profile, monitor) if profile is not None else None
    outputs: list[TopicMessage] = []
    last = 0
    for frame in frames:
        t = frame.timestamp_ns
        if perception is not None:
            perception.advance(t)
        outputs += monitor.advance(t)
        decoded = decoder.decode(frame)
        if type(decoded) is Decoded and perception is not None:
            perception.feed(decoded.codec.message.name, decoded.signals, t)
        monitor.on_frame(frame, decoded)
        last = t
    outputs += monitor.finish(last)
    return Drive(monitor, outputs)


@functools.cache
def ecocar() -> tuple[dict[str | None, list[DatabaseFile]], Profile]:
    """The ecocar databases by bus (None: every bus) and profile, loaded once."""
    decoder, profile = load_stages([], "ecocar")
    assert profile is not None
    databases: dict[str | None, list[DatabaseFile]] = {}
    for f in decoder.files:
        for bus in decoder.buses_for(f):
            databases.setdefault(None if bus == "*" else bus, []).append(f)
    return databases, profile


@functools.cache
def drive(scenario: str) -> Drive:
    """A simulated scenario of its own length, ecocar profile, a 1 Mbit/s bus (2 Mbit/s FD)."""
    databases, profile = ecocar()
    frames = simulate(duration_s=SCENARIOS[scenario].duration_s, scenario=scenario)
    return run(frames, Decoder(databases), profile, bitrates={"can0": BITRATE},
               data_bitrates={"can0": DATA_BITRATE})


# --- the scenarios ----------------------------------------------------------------------------

FAULTS = {
    "radar_dropout": "radar.silent",
    "radar_yaw": "radar-camera.misaligned",
    "radar_blind": "radar.blind",
    "radar_slow": "radar.rate",
    "lane_loss": "lanes.lost",
    "bus_silent": "bus.can0.silent",
    "babbling": "bus.can0.babbling",
}


@pytest.mark.slow
def test_a_clean_drive_raises_no_alarm_over_its_whole_length() -> None:
    clean = drive("clean")
    assert clean.events() == []
    health = clean.health()
    assert len(health) == pytest.approx(SCENARIOS["clean"].duration_s, abs=1)  # 1 Hz
    assert all(h.active_alarms == 0 for _, h in health)
    for t, h in health[2:]:
        for family in h.families:
            assert family.expected_source == "dbc"
            assert 0.8 < family.rate_ratio < 1.2, (t, family)
            assert not family.silent and 0 <= family.age_s < 0.1
        bias = h.biases[0]
        assert bias.pair == "radar-camera" and bias.matches >= 8
        assert abs(bias.angular_offset_deg) < 0.6 and abs(bias.lateral_offset_m) < 0.4


@pytest.mark.slow
@pytest.mark.parametrize(("scenario", "alarm"), FAULTS.items())
def test_each_fault_raises_its_alarm_within_two_seconds_and_clears_after_recovery(
        scenario: str, alarm: str) -> None:
    events = drive(scenario).events()
    assert {alarm_id for alarm_id, _, _ in events} == {alarm}  # and no other alarm
    (_, raised, t_raised), (_, cleared, t_cleared) = events
    assert raised == "raised" and FAULT_ONSET_S < t_raised <= FAULT_ONSET_S + 2.0
    limit = FAULT_RECOVERY_S + SETTINGS.clear_after_s + 1.0
    assert cleared == "cleared" and FAULT_RECOVERY_S < t_cleared <= limit


def test_each_fault_scenario_is_tested() -> None:
    assert set(SCENARIOS) == {"drive", "clean", *FAULTS}


def test_alarms_go_to_the_log_when_raised_and_when_cleared() -> None:
    logs = [o for o in drive("radar_dropout").outputs if o.topic == LOG_TOPIC]
    assert [type(o.message) for o in logs] == [Log, Log]
    raised, cleared = (o.message for o in logs)
    assert raised.level == Log.WARNING and raised.message.startswith("ALARM radar.silent: ")
    assert cleared.level == Log.INFO and cleared.message.startswith("cleared radar.silent")
    for out in logs:
        ts = out.message.timestamp
        assert ts.seconds * NS + ts.nanos == out.t_ns
        assert out.message.name == "tankviz.health"


def test_health_shows_the_silent_radar_and_when_its_alarm_was_raised() -> None:
    dropout = drive("radar_dropout")
    before = {f.name: f for f in dropout.health_at(FAULT_ONSET_S - 1).families}
    assert before["radar"].expected_hz == pytest.approx(64 * 20)  # 64 messages every 50 ms
    assert before["radar"].actual_hz == pytest.approx(1280, rel=0.02)
    assert before["radar"].valid_objects > 0
    during = dropout.health_at(FAULT_ONSET_S + 2.5)
    radar = next(f for f in during.families if f.name == "radar")
    assert radar.silent and radar.actual_hz == 0 and radar.age_s > 2.4
    alarm = next(a for a in during.alarms if a.id == "radar.silent")
    assert alarm.active and alarm.subject == "radar" and during.active_alarms == 1
    since = (alarm.since.seconds * NS + alarm.since.nanos - DEFAULT_START_NS) / NS
    assert FAULT_ONSET_S < since <= FAULT_ONSET_S + 2.0
    after = dropout.health_at(FAULT_RECOVERY_S + 4)
    assert not next(a for a in after.alarms if a.id == "radar.silent").active


@pytest.mark.slow
def test_the_yawed_radar_sees_objects_about_three_degrees_to_the_right_of_the_camera() -> None:
    bias = drive("radar_yaw").health_at(FAULT_ONSET_S + 2).biases[0]
    assert (bias.sensor_a, bias.sensor_b) == ("radar", "camera")
    assert -4.0 < bias.angular_offset_deg < -SETTINGS.bias_angle_deg
    assert bias.lateral_offset_m < -0.5 and bias.matches >= SETTINGS.bias_min_matches


@pytest.mark.slow
def test_the_babbling_id_is_named_with_its_rate_and_share() -> None:
    bus = drive("babbling").health_at(FAULT_ONSET_S + 2).buses[0]
    assert bus.top_id == 0x700 and bus.top_id_hz == pytest.approx(1000, rel=0.02)
    assert 0.25 < bus.top_id_share < 0.35  # 1000 of about 3350 frames/s


@pytest.mark.slow
def test_a_silent_bus_is_reported_in_log_time_although_no_frame_comes() -> None:
    silent = drive("bus_silent")
    during = silent.health_at(FAULT_ONSET_S + 3)  # published inside the gap
    bus = during.buses[0]
    assert bus.gap and bus.frames_per_s == 0 and bus.silent_s > 2.5
    assert not bus.HasField("load") or bus.load == 0
    assert silent.health_at(FAULT_RECOVERY_S + 2).buses[0].gaps_total == 1


@pytest.mark.slow
def test_without_cycle_times_in_the_dbc_the_rates_are_learned(tmp_path: Path) -> None:
    text = (data_dir() / "ecocar.dbc").read_text()
    stripped = "\n".join(line for line in text.splitlines()
                         if not line.startswith('BA_ "GenMsgCycleTime"'))
    dbc = tmp_path / "ecocar.dbc"
    dbc.write_text(stripped)
    decoder, profile = load_stages([str(dbc)], "ecocar")
    dropout = run(simulate(duration_s=14.0, scenario="radar_dropout"), decoder, profile)
    radar = next(f for f in dropout.health_at(FAULT_ONSET_S - 1).families if f.name == "radar")
    assert radar.expected_source == "learned"
    assert radar.expected_hz == pytest.approx(1280, rel=0.05)
    (alarm, event, t), *_ = dropout.events()
    assert (alarm, event) == ("radar.silent", "raised") and t <= FAULT_ONSET_S + 2.0


# --- bits on the wire ------------------------------------------------------------------------


def bits(value: int, n: int) -> list[int]:
    return [(value >> i) & 1 for i in range(n - 1, -1, -1)]


def crc(message: list[int], poly: int, width: int, init: int = 0) -> list[int]:
    register = init
    for bit in message:
        top = (register >> (width - 1)) & 1
        register = (register << 1) & ((1 << width) - 1)
        if top ^ bit:
            register ^= poly
    return bits(register, width)


def stuff(message: list[int]) -> list[int]:
    """Dynamic bit stuffing: after five equal bits, one of the other value (which counts)."""
    out: list[int] = []
    last, run = -1, 0
    for bit in message:
        out.append(bit)
        run = run + 1 if bit == last else 1
        last = bit
        if run == 5:
            out.append(1 - bit)
            last, run = 1 - bit, 1
    return out


FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def exact_bits(frame: Frame) -> int:
    """Every bit of a data frame on the wire, built one by one (ISO 11898-1:2015), through the
    interframe space: SOF, arbitration, control, data, CRC (CRC-15; CAN FD: stuff count and
    CRC-17/21 with fixed stuff bits), delimiter, ACK, EOF (7), IFS (3)."""
    data = frame.data
    if frame.is_fd:
        code = next(i for i, n in enumerate(FD_LENGTHS) if n >= len(data))
        data += bytes([0xCC]) * (FD_LENGTHS[code] - len(data))
    else:
        code = len(data)
    head = [0]  # SOF
    if frame.is_extended:  # base id, SRR, IDE, id extension
        head += [*bits(frame.arbitration_id >> 18, 11), 1, 1, *bits(frame.arbitration_id, 18)]
    else:
        head += bits(frame.arbitration_id, 11)
    if frame.is_fd:  # RRS, (IDE), FDF, res, BRS, ESI
        head += [0, *([] if frame.is_extended else [0]), 1, 0, int(frame.bitrate_switch),
                 int(frame.error_state_indicator)]
    else:  # RTR, IDE/r1, r0
        head += [0, 0, 0]
    head += bits(code, 4)
    for byte in data:
        head += bits(byte, 8)
    after_crc = 1 + 1 + 1 + 7 + 3  # CRC delimiter, ACK slot and delimiter, EOF, IFS
    if not frame.is_fd:
        return len(stuff(head + crc(head, 0x4599, 15))) + after_crc
    dynamic = stuff(head)
    count = (len(dynamic) - len(head)) % 8
    gray = count ^ (count >> 1)
    stuff_count = [*bits(gray, 3), bin(gray).count("1") % 2]
    width, poly = (17, 0x1685B) if len(data) <= 16 else (21, 0x102899)
    fixed = stuff_count + crc(dynamic + stuff_count, poly, width, 1 << (width - 1))
    wire = [*dynamic, 1 - dynamic[-1]]  # a fixed stuff bit before the stuff count ...
    for i, bit in enumerate(fixed):
        wire.append(bit)
        if i % 4 == 3:  # ... and after every fourth bit
            wire.append(1 - bit)
    return len(wire) + after_crc


def synthetic_traffic(count: int, *, seed: int = 1, period_ns: int = 500_000,
                      fd: bool = True) -> list[Frame]:
    """A known mix: 11- and 29-bit ids, every length, random payloads and some all-0 and all-1
    (heavy stuffing), CAN FD frames with and without bit rate switch."""
    rng = random.Random(seed)
    frames = []
    for k in range(count):
        extended = rng.random() < 0.3
        is_fd = fd and rng.random() < 0.2
        n = rng.randrange(65) if is_fd else rng.randrange(9)
        kind = rng.random()
        data = (bytes(n) if kind < 0.15 else b"\xff" * n if kind < 0.25 else rng.randbytes(n))
        ident = rng.randrange(1 << 29) if extended else rng.randrange(1 << 11)
        frames.append(Frame(DEFAULT_START_NS + k * period_ns, "can0", ident, data, extended,
                            is_fd, False, False, is_fd and rng.random() < 0.7, False, n))
    return frames


@pytest.mark.slow
def test_the_bit_estimate_is_within_five_percent_of_the_exact_count() -> None:
    frames = synthetic_traffic(3000)
    exact = sum(exact_bits(f) for f in frames)
    estimate = sum(estimate_frame_bits(f) for f in frames)
    assert estimate == pytest.approx(exact, rel=0.05)
    assert estimate == pytest.approx(exact, rel=0.002)  # in fact: only the CRC-15 is estimated
    assert all(abs(estimate_frame_bits(f) - exact_bits(f)) <= 3 for f in frames)


def test_remembered_payloads_count_the_same_as_new_ones() -> None:
    """frame_bits remembers the bits of recent payloads per kind of frame: a payload seen again,
    and one seen again after the memory was emptied (more payloads than it keeps), count the
    same as the first time."""
    rng = random.Random(7)
    payloads = [rng.randbytes(64) for _ in range(300)] + [bytes(64), b"\xff" * 64]
    frames = [Frame(0, "can0", 0x301, data, is_fd=True, bitrate_switch=True, dlc=64)
              for data in payloads]
    first = [frame_bits(f) for f in frames]
    again = [frame_bits(f) for f in reversed(frames)][::-1]
    assert again == first
    assert all(abs(sum(bits) - exact_bits(f)) <= 3 for bits, f in zip(first, frames, strict=True))
    assert first[-2] != first[-1]  # zeros and ones stuff differently: keyed by the payload


def test_a_classic_frame_of_eight_bytes_is_at_least_111_bits() -> None:
    frame = Frame(0, "can0", 0x555, bytes([0x55] * 8), dlc=8)  # alternating bits: no stuffing
    assert estimate_frame_bits(frame) == pytest.approx(111, abs=1)
    assert exact_bits(frame) == pytest.approx(111, abs=1)
    assert estimate_frame_bits(frame._replace(data=bytes(8))) > 111 + 10  # zeros get stuffed


def test_the_data_phase_of_a_bit_rate_switched_frame_counts_at_the_data_bitrate() -> None:
    frame = Frame(0, "can0", 0x301, bytes(range(64)), is_fd=True, bitrate_switch=True, dlc=64)
    arbitration, data_phase = frame_bits(frame)
    assert 25 < arbitration < 40 and data_phase > 8 * 64
    assert estimate_frame_bits(frame, bitrate=500_000, data_bitrate=2_000_000) == pytest.approx(
        arbitration + data_phase / 4)
    assert estimate_frame_bits(frame) == arbitration + data_phase


@pytest.mark.slow
def test_the_bus_load_of_known_traffic_is_within_five_percent() -> None:
    frames = synthetic_traffic(8000)  # 2000 frames/s for 4 s
    bus = run(frames, Decoder({}), None, bitrates={"can0": 2_000_000},
              data_bitrates={"can0": 4_000_000}).health_at(3.0).buses[0]
    window = [f for f in frames if 2 * NS <= f.timestamp_ns - DEFAULT_START_NS < 3 * NS]
    seconds = 0.0
    for f in window:
        arbitration, data_phase = frame_bits(f)
        share = data_phase / (arbitration + data_phase)  # the exact bits, split like the estimate
        seconds += exact_bits(f) * ((1 - share) / 2_000_000 + share / 4_000_000)
    assert bus.frames_per_s == pytest.approx(2000, rel=0.01)
    assert bus.load == pytest.approx(seconds, rel=0.05)
    assert bus.unknown_ids == len(window) and bus.bitrate == 2_000_000


@pytest.mark.slow
def test_without_a_bitrate_the_load_is_not_guessed() -> None:
    classic = synthetic_traffic(4000, fd=False)
    bus = run(classic, Decoder({}), None).health_at(1.0).buses[0]
    assert not bus.HasField("load") and bus.bits_per_s > 0 and bus.bitrate == 0
    with_fd = synthetic_traffic(4000)
    bus = run(with_fd, Decoder({}), None, bitrates={"can0": 500_000}).health_at(1.0).buses[0]
    assert not bus.HasField("load")  # bit-rate-switched frames, but no data bitrate
    assert run(classic, Decoder({}), None, bitrates={"can0": 500_000}).health_at(
        1.0).buses[0].HasField("load")


# --- bus traffic without a profile ------------------------------------------------------------


def test_an_unknown_id_flooding_a_bus_is_babbling() -> None:
    frames = [Frame(DEFAULT_START_NS + k * 10_000_000, "can0", ident, bytes(8))
              for k in range(800) for ident in (0x10, 0x20, 0x30)]  # 100 Hz each, 8 s
    frames += [Frame(DEFAULT_START_NS + 2 * NS + k * 1_000_000, "can0", 0x7E5, bytes(8))
               for k in range(2000)]  # 1 kHz from 2 s to 4 s
    flood = run(sorted(frames), Decoder({}), None)
    assert [(a, e) for a, e, _ in flood.events()] == [("bus.can0.babbling", "raised"),
                                                      ("bus.can0.babbling", "cleared")]
    raised = flood.events()[0][2]
    assert 2.0 < raised <= 4.0
    alarm = next(a for a in flood.health_at(4.0).alarms if a.id == "bus.can0.babbling")
    assert "0x7E5" in alarm.message and alarm.active


def test_error_frames_unknown_ids_and_bad_payloads_are_counted_per_bus() -> None:
    decoder, profile = load_stages([], "ecocar")
    ecocar = load_ecocar()
    diag = ecocar.get_message_by_name("SensorDiag")
    frames = []
    for k in range(120):
        t = DEFAULT_START_NS + k * 10_000_000
        frames += [Frame(t, "can0", 0x7FF, bytes(8)),  # unknown
                   Frame(t + 1000, "can0", 0, b"", is_error=True),
                   Frame(t + 2000, "can0", diag.frame_id, bytes([9]) + bytes(7))]  # bad mux
    bus = run(frames, decoder, profile).health_at(1.0).buses[0]  # 100 of each so far
    assert bus.unknown_ids_total == bus.error_frames_total == bus.decode_errors_total == 100
    assert bus.unknown_ids == bus.error_frames == bus.decode_errors == 90  # since 0.1 s


# --- the scene --------------------------------------------------------------------------------


def test_active_alarms_show_above_the_ego_and_turn_their_sensor_outline_red() -> None:
    _, profile = load_stages([], "ecocar")
    assert profile is not None
    t = DEFAULT_START_NS
    alarm = AlarmInfo("radar.silent", AlarmKind.SENSOR_SILENT, "radar",
                      "radar: no frame for 1.3 s", t, ("radar",))
    (overlay,) = alarm_entities([alarm], t)
    (label,) = overlay.texts
    assert label.text == "HEALTH: 1 ALARM\nradar.silent"
    # many alarms: their ids in lines a laptop's narrowest panel (442 px) holds, at 18 px
    names = ("radar.silent", "radar-camera.misaligned", "lanes.lost", "bus.chassis_can.babbling")
    many = [dataclasses.replace(alarm, id=name) for name in names]
    (words,) = alarm_entities(many, t)[0].texts
    header, *lines = words.text.split("\n")
    assert header == "HEALTH: 4 ALARMS" and " ".join(lines) == ", ".join(names)
    assert max(map(len, lines)) * 0.65 * words.font_size < 442
    assert label.color.r == 1.0 and label.color.a == 1.0 and label.font_size > 0
    assert label.pose.orientation.w == 1.0 and overlay.frame_id == "vehicle"
    outlines = {e.id: e for e in fov_entities(profile, [alarm], t)}
    assert set(outlines) == {"fov-radar", "fov-camera"}  # the fusion has no field of view
    radar, camera = outlines["fov-radar"].lines[0], outlines["fov-camera"].lines[0]
    assert radar.color.r == 1.0 and radar.color.a > 0.5 and radar.thickness > camera.thickness
    assert camera.color.a < 0.5 and camera.thickness > 0  # dim, but visible
    assert outlines["fov-radar"].texts[0].text == "radar: radar.silent"
    assert not outlines["fov-camera"].texts
    far = max(p.x for p in radar.points)
    assert far == pytest.approx(160.0)  # the profile's radar range
    assert alarm_entities([], t) == []


def test_the_monitor_lists_active_alarms_for_the_overlay() -> None:
    dropout = drive("radar_dropout")
    assert dropout.monitor.active_alarms() == []  # all cleared by the end
    assert {"radar.silent", "camera.blind", "radar-camera.misaligned", "lanes.lost",
            "bus.can0.silent", "bus.can0.babbling"} <= set(dropout.monitor.alarm_ids())


def test_alarm_ids_are_made_in_one_place_as_its_table_says() -> None:
    """alarm_id gives every kind the id the table of bridge.health.alarms shows for it (each
    kind once), so the table and the ids cannot drift apart."""
    assert alarm_id(AlarmKind.SENSOR_SILENT, "radar") == "radar.silent"
    assert alarm_id(AlarmKind.RATE_LOW, "ego") == "ego.rate"
    assert alarm_id(AlarmKind.NO_OBJECTS, "camera") == "camera.blind"
    assert alarm_id(AlarmKind.MISALIGNED, "radar-camera") == "radar-camera.misaligned"
    assert alarm_id(AlarmKind.LANES_LOST, "lanes") == "lanes.lost"
    assert alarm_id(AlarmKind.BUS_SILENT, "can0") == "bus.can0.silent"
    assert alarm_id(AlarmKind.BABBLING, "can0") == "bus.can0.babbling"
    assert alarm_id(AlarmKind.DISK_FULL, "recorder") == "recorder.disk_full"
    assert alarm_id(AlarmKind.FRAMES_LOST, "can1") == "bus.can1.frames_lost"
    assert alarm_id(AlarmKind.BAD_TIMESTAMPS, "can1") == "bus.can1.bad_timestamps"
    doc = alarms.__doc__ or ""
    rows = re.findall(r"^``(\S+)``\s+``([A-Z_]+)``", doc, re.MULTILINE)
    assert sorted(kind for _, kind in rows) == sorted(k.name for k in AlarmKind)
    for ident, kind in rows:
        subject = re.fullmatch(re.escape(AlarmKind[kind].value).replace(r"\{\}", "(.+)"), ident)
        assert subject is not None, (ident, kind)
        assert alarm_id(AlarmKind[kind], subject.group(1)) == ident


def test_alarm_notices_carry_their_log_level() -> None:
    raised = alarm_notice(AlarmKind.DISK_FULL, "recorder", "disk full (/drives)")
    cleared = alarm_notice(AlarmKind.DISK_FULL, "recorder", "recording resumed", cleared=True)
    assert (raised, raised.level) == ("recorder.disk_full: disk full (/drives)", Log.WARNING)
    assert (cleared, cleared.level) == ("recorder.disk_full cleared: recording resumed",
                                        Log.INFO)


def test_settings_must_be_positive() -> None:
    with pytest.raises(UsageError, match="window_s"):
        HealthSettings(window_s=0)
    with pytest.raises(UsageError, match="rate_threshold"):
        HealthSettings(rate_threshold=1.5)
