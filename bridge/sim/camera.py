"""The front camera: CamObstacle0..9 (A and B) and the four lane lines, every 66 ms.

The camera reports y positive RIGHT (as its DBC comments say): every lateral position and every
lane coefficient has the opposite sign of the world's (y positive left). ``lane_dropout`` blanks
the lanes, never the obstacles.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterator

from bridge.frame import Frame
from bridge.sim.frames import Codec, Ids, Run, Slots
from bridge.sim.world import CAM_TRUCK, CAM_VEHICLE, LANE_WIDTH_M


def _lane_fit_matrix(xs: list[float]) -> list[list[float]]:
    """The least-squares cubic fit y(x) = c0 + c1 x + c2 x^2 + c3 x^3 as a 4 x n matrix."""
    a = [[x**p for p in range(4)] for x in xs]
    ata = [[sum(row[i] * row[j] for row in a) for j in range(4)] for i in range(4)]
    inverse = [[float(i == j) for j in range(4)] for i in range(4)]
    for col in range(4):  # Gauss-Jordan
        pivot = ata[col][col]
        ata[col] = [v / pivot for v in ata[col]]
        inverse[col] = [v / pivot for v in inverse[col]]
        for row in range(4):
            if row != col:
                f = ata[row][col]
                ata[row] = [v - f * w for v, w in zip(ata[row], ata[col], strict=True)]
                inverse[row] = [v - f * w for v, w in zip(inverse[row], inverse[col], strict=True)]
    return [[sum(inverse[i][k] * a[n][k] for k in range(4)) for n in range(len(xs))]
            for i in range(4)]


_LANE_XS = [5.0 * i for i in range(17)]  # 0..80 m
_LANE_FIT = _lane_fit_matrix(_LANE_XS)

# Camera lane lines: (message, offset of the line from the ego lane centre (left), type, range).
LANES = (("CamLaneLeft", LANE_WIDTH_M / 2, 0, 80),
         ("CamLaneRight", -LANE_WIDTH_M / 2, 0, 80),
         ("CamLaneNextLeft", 1.5 * LANE_WIDTH_M, 4, 60),
         ("CamLaneNextRight", -1.5 * LANE_WIDTH_M, 1, 60))


def camera(run: Run) -> Iterator[Frame]:
    """CamObstacle0..9 A and B, then the four lane lines, every 66 ms.

    - Obstacles: the 10 nearest actors the camera covers (:mod:`bridge.sim.sensors`), each keeping
      its slot and obstacle id while it is visible; an unused slot is zeros (but its counter). An
      obstacle has its actor's camera type and size, a status (oncoming, moving or stopped), its
      lane (ego lane, next lane), its age, and for vehicles brake lights while it decelerates, the
      cut-in flag and the left blinker for the ``cut_in`` car from a second before its lane change
      to its end.
    - Lanes (``CamLaneLeft``, ``CamLaneRight``, ``CamLaneNextLeft``, ``CamLaneNextRight``): the
      least-squares cubic ``C0 + C1 x + C2 x^2 + C3 x^3`` of the road's ego lane centre 0..80 m
      ahead, relative to the ego's lateral offset and heading, moved out to each line (half a lane
      width for the ego lane's lines, one and a half for the neighbours'), with noise: ``C0`` about
      -1.8 m (left) and +1.8 m (right), ``C2`` about half the path curvature; ``Source`` camera,
      ``Quality`` high. Lane frames have their own rolling counter, modulo 4.
    - ``lane_dropout`` (``drive``'s episode, ``lane_loss``): every lane frame with a timestamp
      inside the window reports no lanes (``Source`` none, ``Quality`` none, coefficients 0); the
      obstacles carry on.
    """
    rng = run.rng("Camera")
    obstacles = [(run.codec(f"CamObstacle{i}_A"), run.codec(f"CamObstacle{i}_B"))
                 for i in range(10)]
    lanes = [(run.codec(name), offset, kind, view) for name, offset, kind, view in LANES]
    counter = rng.randrange(16)
    lane_counter = rng.randrange(4)
    slots = Slots(10)
    ids = Ids(rng.randrange(1, 200))
    age: dict[Hashable, int] = {}
    dropout = run.faults.lane_dropout
    sc = run.world.scenario
    n_frames = 2 * len(obstacles) + len(lanes)
    for tick, ts in run.ticks(rng, 66, (0, 20_000)):
        times = run.burst(rng, ts, n_frames)
        if times[0] >= run.end_ns:
            return
        snap = run.world.at(tick)
        t = snap.t
        visible = sorted((s for s in snap.objects if s.camera), key=lambda s: s.range)[:10]
        by_key = {s.key: s for s in visible}
        owners = slots.assign([s.key for s in visible])
        ids.retain(set(by_key))
        for key in [k for k in age if k not in by_key]:
            del age[key]
        frames: list[tuple[Codec, bytes]] = []
        for slot, (codec_a, codec_b) in enumerate(obstacles):
            key = owners[slot]
            if key is None:
                frames.append((codec_a, codec_a.encode({
                    "ObstacleID": 0, "PosX": 0, "PosY": 0, "RelVelX": 0, "Type": 0, "Status": 0,
                    "Valid": 0, "BrakeLights": 0, "CutInOut": 0, "Blinker": 0,
                    "Counter": counter})))
                frames.append((codec_b, codec_b.encode({
                    "ObstacleID": 0, "Width": 0, "Length": 0, "Age": 0, "Lane": 0,
                    "RelAccelX": 0, "Counter": counter})))
                continue
            s = by_key[key]
            actor = s.actor
            obstacle_id = ids.get(key)
            n = age[key] = min(255, age.get(key, 0) + 1)
            vehicle = actor.camera_type in (CAM_VEHICLE, CAM_TRUCK)
            changing = actor.name == "cut_in" and sc.t_cut - 1.0 <= t < sc.t_cut + sc.cut_duration
            in_lane = abs(s.d) < LANE_WIDTH_M / 2
            lane = 1 if in_lane else 2 if abs(s.d) < 1.5 * LANE_WIDTH_M else 0
            if s.v_abs < -1.0:
                status = 4  # oncoming
            elif abs(s.v_abs) > 0.5:
                status = 3  # moving
            else:
                status = 2  # stopped
            frames.append((codec_a, codec_a.encode({
                "ObstacleID": obstacle_id,
                "PosX": s.x + rng.gauss(0, 0.05 + 0.01 * s.x),
                "PosY": -(s.y + rng.gauss(0, 0.08)),  # camera: y positive RIGHT
                "RelVelX": s.vx + rng.gauss(0, 0.15),
                "Type": actor.camera_type, "Status": status, "Valid": 1,
                "BrakeLights": int(vehicle and s.a_abs < -1.0),
                "CutInOut": (3 if changing else 1 if in_lane else 2) if vehicle else 0,
                "Blinker": (2 if changing else 1) if vehicle else 0,
                "Counter": counter})))
            frames.append((codec_b, codec_b.encode({
                "ObstacleID": obstacle_id, "Width": actor.width + rng.gauss(0, 0.03),
                "Length": actor.length, "Age": n, "Lane": lane,
                "RelAccelX": s.ax + rng.gauss(0, 0.1), "Counter": counter})))
        lane_times = times[len(frames):]
        centre = [sc.road_y(snap.ego, x) for x in _LANE_XS]
        fit = [sum(m * y for m, y in zip(row, centre, strict=True)) for row in _LANE_FIT]
        c0, c1, c2, c3 = fit[0] - snap.ego.d, fit[1] - snap.ego.psi, fit[2], fit[3]
        for when, (codec, offset, kind, view) in zip(lane_times, lanes, strict=True):
            if dropout[0] <= when < dropout[1]:
                values: dict[str, float] = {
                    "C0_Offset": 0, "C1_Heading": 0, "C2_Curvature": 0,
                    "C3_CurvatureDerivative": 0, "Quality": 0, "LaneType": 7, "Source": 0,
                    "ViewRange": 0, "Counter": lane_counter}
            else:  # the camera reports y positive RIGHT: every coefficient changes sign
                values = {
                    "C0_Offset": -(c0 + offset + rng.gauss(0, 0.02)),
                    "C1_Heading": -(c1 + rng.gauss(0, 0.0008)),
                    "C2_Curvature": -(c2 + rng.gauss(0, 0.00002)),
                    "C3_CurvatureDerivative": -(c3 + rng.gauss(0, 0.0000002)),
                    "Quality": 3, "LaneType": kind, "Source": 1,
                    "ViewRange": view - rng.randrange(4), "Counter": lane_counter}
            frames.append((codec, codec.encode(values)))
        for when, (codec, data) in zip(times, frames, strict=True):
            if when >= run.end_ns:
                return
            yield run.out.frame(when, codec, data)
        counter = (counter + 1) % 16
        lane_counter = (lane_counter + 1) % 4
