"""The gateway: SensorDiag diagnostics, and the babbling gateway of the ``babbling`` scenario.

``SensorDiag`` comes every second, cycling its pages; while the radar misalignment is reported
(``misalignment_reported``) the radar's error page has one active DTC. ``babbling`` adds a stuck
gateway's repeated frame on top of the traffic.
"""

from __future__ import annotations

from collections.abc import Iterator

from bridge.frame import NS, Frame
from bridge.sim.frames import US, Run
from bridge.sim.scenario import BABBLE_PERIOD_US


def diagnostics(run: Run) -> Iterator[Frame]:
    """SensorDiag every second, cycling pages 0..3 (firmware, temperature, power, errors); the
    source (radar, camera, fusion, gateway) changes after each full turn.
    """
    rng = run.rng("SensorDiag")
    codec = run.codec("SensorDiag")
    counter = rng.randrange(codec.counter_mod)
    misaligned = run.faults.misalignment_reported
    uptime_min = rng.randrange(2, 120)
    for k, (tick, ts) in enumerate(run.ticks(rng, 1000, (200_000, 400_000))):
        if ts >= run.end_ns:
            return
        t = tick / NS
        page, source = k % 4, (k // 4) % 4
        values: dict[str, float] = {"DiagPage": page, "DiagSource": source, "Counter": counter}
        if page == 0:
            values.update(FwVersionMajor=2, FwVersionMinor=4 + source, FwVersionPatch=1,
                          HwRevision=3, SerialNumber=41_000 + 17 * source)
        elif page == 1:
            values.update(TempCore=55 + 0.02 * t + rng.gauss(0, 0.5), TempBoard=47 + 0.01 * t,
                          TempHousing=33 + 0.01 * t, HeaterActive=0)
        elif page == 2:
            values.update(SupplyVoltage=13.8 + rng.gauss(0, 0.05),
                          SupplyCurrent=0.45 + 0.1 * source + rng.gauss(0, 0.01), PowerMode=1)
        else:
            fault = source == 0 and misaligned[0] <= ts < misaligned[1]
            values.update(ActiveDtcCount=1 if fault else 0, LastDtc=0xC2_34_00 if fault else 0,
                          UptimeMinutes=uptime_min + int(t // 60))
        yield run.out.frame(ts, codec, codec.encode(values))
        counter = (counter + 1) % codec.counter_mod


def babbler(run: Run) -> Iterator[Frame]:
    """``babbling``: a stuck gateway repeats one SensorDiag frame (page 0) every
    :data:`BABBLE_PERIOD_US` microseconds during the fault, on top of the traffic (its own
    ``SensorDiag`` carries on once a second).
    """
    codec = run.codec("SensorDiag")
    data = codec.encode({"DiagPage": 0, "DiagSource": 0, "Counter": 0, "FwVersionMajor": 2,
                         "FwVersionMinor": 4, "FwVersionPatch": 1, "HwRevision": 3,
                         "SerialNumber": 41_000})
    begin, end = run.faults.babbling
    ts = begin
    while ts < min(end, run.end_ns):
        yield run.out.frame(ts, codec, data)
        ts += BABBLE_PERIOD_US * US
