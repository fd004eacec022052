"""The end of a drive: the frames after the last full scene period are drawn too.

A drive's scene ticks are on the scene rate's grid, each made when the first frame at or after
its time arrives. The frames after the last tick (up to one period of them) reach a scene only
through the final tick that :meth:`bridge.pipeline.pipeline.Pipeline.finish` makes at the end
of the input: the next tick of the grid, which the next frame would have made.
"""

from __future__ import annotations

from collections.abc import Sequence

from bridge.frame import Frame
from bridge.pipeline.drive import Drive, load_stages
from bridge.sim.ecocar import simulate
from bridge.sinks.base import Serialized, Sink

PERIOD_NS = 50_000_000  # the default scene rate, 20 Hz


class Scenes(Sink):
    """The log times of the ego scenes a drive makes."""

    def __init__(self) -> None:
        self.times: list[int] = []

    def on_messages(self, messages: Sequence[Serialized], /) -> None:
        self.times += [m.t_ns for m in messages if m.topic == "/scene/ego"]


def scenes_of(frames: list[Frame]) -> list[int]:
    scenes = Scenes()
    drive = Drive(load_stages([], "ecocar"), [scenes])
    drive.run(frames)
    drive.finish()
    return scenes.times


def test_the_frames_after_the_last_full_period_reach_a_final_scene() -> None:
    frames = list(simulate(duration_s=1.0))
    last = frames[-1].timestamp_ns
    times = scenes_of(frames)
    assert times[-1] > last, "the last frames were decoded but never drawn"
    assert times[-1] % PERIOD_NS == 0 and times[-1] - last <= PERIOD_NS  # on the grid
    assert len(times) == len(set(times))


def test_the_final_scene_is_made_once() -> None:
    frames = list(simulate(duration_s=1.0))
    scenes = Scenes()
    drive = Drive(load_stages([], "ecocar"), [scenes])
    drive.run(frames)
    drive.pipeline.finish()
    drive.pipeline.finish()
    assert scenes.times == sorted(set(scenes.times))
