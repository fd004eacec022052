"""Sensor fusion: FusionTrack0..19 then LeadVehicle, every 50 ms, y positive LEFT.

Every object the radar or the camera covers is a track, coasted for up to three cycles once no
sensor covers it; ``LeadVehicle`` is the closest track ahead in the ego lane, so the ``cut_in``
car becomes the lead once inside the ego lane.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterator
from dataclasses import dataclass

from bridge.frame import Frame
from bridge.sim.frames import Codec, Ids, Run, Slots
from bridge.sim.world import CLASS_FOUR_WHEEL, CLASS_TWO_WHEEL


@dataclass
class _Track:
    x: float
    y: float
    vx: float
    vy: float
    cls: int
    d: float
    age: int = 0
    missing: int = 0


def fusion(run: Run) -> Iterator[Frame]:
    """FusionTrack0..19 then LeadVehicle every 50 ms (radar + camera fused, y positive left).

    - Tracks: every object the radar or the camera covers (:mod:`bridge.sim.sensors`; the radar only
      while it sends valid objects: not during ``radar_dropout`` or ``radar_blind``; spurious radar
      detections never), with a confidence by source (radar and camera, radar alone, camera alone),
      status new for its first two cycles, then updated; an object no sensor covers any more is
      coasted (predicted, status coasted) for up to three cycles, then dropped. Tracks are sent
      nearest first, coasted ones last; a track keeps its slot and its track id while it is tracked;
      an unused slot is zeros (but its counter).
    - ``LeadVehicle``: the closest track ahead in the ego lane (four-wheel or two-wheel): its track
      id, position, relative speed, time gap and time to collision; ``Valid`` 0 without one.
    """
    rng = run.rng("Fusion")
    tracks_codecs = [run.codec(f"FusionTrack{i}") for i in range(20)]
    lead_codec = run.codec("LeadVehicle")
    counter = rng.randrange(16)
    lead_counter = rng.randrange(16)
    slots = Slots(20)
    ids = Ids(rng.randrange(1, 100))
    tracks: dict[Hashable, _Track] = {}
    radar_out = run.faults.radar_dropout
    radar_blind = run.faults.radar_blind
    for tick, ts in run.ticks(rng, 50, (18_000, 28_000)):
        times = run.burst(rng, ts, len(tracks_codecs) + 1)
        if times[0] >= run.end_ns:
            return
        snap = run.world.at(tick)
        radar_ok = not (radar_out[0] <= ts < radar_out[1] or radar_blind[0] <= ts < radar_blind[1])
        sources: dict[Hashable, int] = {}
        for s in snap.objects:
            by_radar, by_camera = s.radar and radar_ok, s.camera
            if by_radar or by_camera:
                sources[s.key] = int(by_radar) + 2 * int(by_camera)
                old = tracks.get(s.key)
                track = _Track(s.x, s.y, s.vx, s.vy, s.actor.radar_class, s.d)
                track.age = old.age + 1 if old is not None else 0
                tracks[s.key] = track
        for key in [k for k in tracks if k not in sources]:
            track = tracks[key]  # coast for a few cycles, then drop
            track.missing += 1
            track.x += track.vx * 0.05
            track.y += track.vy * 0.05
            if track.missing > 3 or track.x < 0.5:
                del tracks[key]
        ordered = sorted(tracks, key=lambda k: (tracks[k].missing > 0,
                                                tracks[k].x**2 + tracks[k].y**2))
        owners = slots.assign(ordered)
        ids.retain(set(tracks))
        frames: list[tuple[Codec, bytes]] = []
        fused: dict[Hashable, tuple[int, float, float, float]] = {}
        for slot, codec in enumerate(tracks_codecs):
            key = owners[slot]
            if key is None:
                frames.append((codec, codec.encode({
                    "TrackID": 0, "PosX": 0, "PosY": 0, "RelVelX": 0, "RelVelY": 0, "Class": 0,
                    "Status": 0, "Confidence": 0, "Counter": counter})))
                continue
            track = tracks[key]
            track_id = ids.get(key)
            source = sources.get(key, 0)
            if track.missing:
                status, confidence = 3, 50.0  # coasted
            else:
                status = 1 if track.age < 2 else 2  # new / updated
                confidence = {3: 96.875, 1: 81.25, 2: 71.875}[source]
            x = track.x + rng.gauss(0, 0.05)
            y = track.y + rng.gauss(0, 0.04)
            vx = track.vx + rng.gauss(0, 0.05)
            fused[key] = (track_id, x, y, vx)
            frames.append((codec, codec.encode({
                "TrackID": track_id, "PosX": x, "PosY": y, "RelVelX": vx,
                "RelVelY": track.vy + rng.gauss(0, 0.05), "Class": track.cls, "Status": status,
                "Confidence": confidence, "Counter": counter})))
        # Lead vehicle: the closest in-lane vehicle or two-wheeler ahead.
        candidates = [k for k in fused if abs(tracks[k].d) < 1.6 and fused[k][1] > 0.0
                      and tracks[k].cls in (CLASS_FOUR_WHEEL, CLASS_TWO_WHEEL)]
        ego_v = snap.ego.v
        if candidates:
            track_id, x, y, vx = fused[min(candidates, key=lambda k: fused[k][1])]
            values: dict[str, float] = {
                "Valid": 1, "AccState": 2, "Counter": lead_counter, "TrackID": track_id,
                "PosX": x, "PosY": y, "RelVelX": vx,
                "TimeGap": min(6.3, x / ego_v) if ego_v > 0.1 else 6.3,
                "TTC": min(102.3, x / -vx) if vx < -0.1 else 102.3}
        else:
            values = {"Valid": 0, "AccState": 2, "Counter": lead_counter, "TrackID": 0,
                      "PosX": 0, "PosY": 0, "RelVelX": 0, "TimeGap": 6.3, "TTC": 102.3}
        frames.append((lead_codec, lead_codec.encode(values)))
        for when, (codec, data) in zip(times, frames, strict=True):
            if when >= run.end_ns:
                return
            yield run.out.frame(when, codec, data)
        counter = (counter + 1) % 16
        lead_counter = (lead_counter + 1) % 16
