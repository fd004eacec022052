"""The cameras a profile is viewed from, and how big a metre looks in each.

The generated layouts (:mod:`bridge.view.generate`) have two 3D views (:data:`VIEWS`): the chase
view (:func:`chase_camera`), close behind the car, and the range view (:func:`camera_for`), from
:data:`BEHIND_M` behind the vehicle origin to just beyond the profile's farthest sensor range
(:func:`view_range`), looking :data:`DEPRESSION_DEG` down. Each is laid out for the smallest panel
the layouts give it in a 1280 x 800 window (:data:`RANGE_PANEL`, :data:`CHASE_PANEL`): on a panel
as tall or taller and as wide or wider for its height, labels apart and on the small panel stay so
(:meth:`ViewCamera.holds`); the scene keeps every mark visible in the range view
(:meth:`ViewCamera.scale`). These are defaults: the camera can still be moved in Foxglove.

Foxglove's camera state: ``distance`` from the eye to the target, ``phi`` the angle of the line of
sight from straight down (degrees), ``targetOffset`` the target in the followed frame, ``fovy``
the vertical field of view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache

from bridge.profile.model import Profile

#: The line of sight's angle below the horizon (degrees).
DEPRESSION_DEG = 40.0
#: Foxglove's default vertical field of view (degrees).
FOVY_DEG = 45.0
#: The bottom edge of the view meets the ground this far (m) behind the vehicle origin.
BEHIND_M = 6.0
#: The top edge of the view lies this much beyond the range (share of the range): room for the
#: labels above the farthest objects.
BEYOND = 0.16
#: The smallest panel of each view (height px, width-to-height ratio): Foxglove Studio's 3D
#: panels of the generated layouts in a 1280 x 800 window, measured a little under. The range
#: view: tank-viz's right panel, 553 x 693. The chase view: engineer's, 442 x 498 (tank-viz's,
#: above its Mark button, is 676 x 585). In a 1920 x 1080 window they are 841 x 973, 673 x 702
#: and 1028 x 823.
RANGE_PANEL = (680.0, 0.79)
CHASE_PANEL = (490.0, 0.88)
#: The chase view's camera: close behind and above the vehicle, 30 degrees down to a target
#: 16 m ahead, 40 m from the eye (the seed's view).
CHASE_DEPRESSION_DEG, CHASE_TARGET_M, CHASE_DISTANCE_M = 30.0, 16.0, 40.0
#: The view covers at least this much road (m), however short the sensors' reach.
MIN_RANGE_M = 60.0
#: A mark is drawn at least this many pixels wide on the range view's smallest panel (a
#: detection ball, at its base size DETECTION_SIZE; every other mark grows with it): about 6 px
#: in a 1600 x 1000 window.
MIN_MARK_PX = 4.5


@dataclass(frozen=True)
class ViewCamera:
    """A camera behind the vehicle, looking forward and down (vehicle frame)."""

    eye_x: float  # m, behind the origin: negative
    eye_z: float  # m, above the ground
    depression_deg: float = DEPRESSION_DEG
    fovy_deg: float = FOVY_DEG
    height_px: float = RANGE_PANEL[0]
    aspect: float = RANGE_PANEL[1]

    @property
    def distance(self) -> float:
        """From the eye to the target, where the line of sight meets the ground."""
        return self.eye_z / math.sin(math.radians(self.depression_deg))

    @property
    def target_x(self) -> float:
        return self.eye_x + self.eye_z / math.tan(math.radians(self.depression_deg))

    @cached_property
    def focal_px(self) -> float:
        """Pixels per unit of tangent: a metre at depth d is focal_px / d pixels."""
        return self.height_px / 2 / math.tan(math.radians(self.fovy_deg) / 2)

    @cached_property
    def _sight(self) -> tuple[float, float]:
        """Cosine and sine of the line of sight's angle below the horizon."""
        a = math.radians(self.depression_deg)
        return math.cos(a), math.sin(a)

    @property
    def sight(self) -> tuple[float, float]:
        """Cosine and sine of the line of sight's angle below the horizon: the terms of
        :meth:`project`, :meth:`px_per_m` and :meth:`scale`, for a caller that spells them out
        over many points (the scene's marks and labels)."""
        return self._sight

    @property
    def vertical(self) -> float:
        """How much of a vertical metre shows on the panel (a share of a metre across)."""
        return self._sight[0]

    def depth(self, x: float, y: float, z: float) -> float:
        """How far (m) the point lies ahead of the eye along the line of sight."""
        cos, sin = self._sight
        return (x - self.eye_x) * cos - (z - self.eye_z) * sin

    def project(self, x: float, y: float, z: float) -> tuple[float, float] | None:
        """The point on the panel (px from its centre: right, down), None behind the eye."""
        cos, sin = self._sight
        d = (x - self.eye_x) * cos - (z - self.eye_z) * sin
        if d <= 0.1:
            return None
        up = (x - self.eye_x) * sin + (z - self.eye_z) * cos
        return -y * self.focal_px / d, -up * self.focal_px / d

    def on_panel(self, left: float, top: float, right: float, bottom: float) -> bool:
        """Whether a box (px from the panel's centre: right, down) lies wholly on the panel."""
        half_h, half_w = self.height_px / 2, self.height_px * self.aspect / 2
        return -half_w <= left and right <= half_w and -half_h <= top and bottom <= half_h

    def holds(self, height_px: float, width_px: float) -> bool:
        """Whether labels laid out for this camera's panel are apart and on a panel of this
        size too: as tall or taller, and as wide or wider for its height."""
        return height_px >= self.height_px and width_px >= self.aspect * height_px

    def px_per_m(self, x: float, y: float, z: float = 0.0) -> float:
        """How many pixels a metre across the line of sight takes at the point."""
        cos, sin = self._sight  # depth(x, y, z), inline
        return self.focal_px / max((x - self.eye_x) * cos - (z - self.eye_z) * sin, 0.1)

    def scale(self, x: float, y: float, base_m: float, min_px: float = MIN_MARK_PX) -> float:
        """The factor (>= 1) that makes a mark of ``base_m`` at (x, y) at least ``min_px``
        wide on the panel."""
        cos, sin = self._sight  # px_per_m(x, y) at z = 0, inline (a few calls a mark)
        px = self.focal_px / max((x - self.eye_x) * cos - (0.0 - self.eye_z) * sin, 0.1)
        return max(1.0, min_px / (base_m * px))

    def foxglove_state(self) -> dict[str, object]:
        """The 3D panel's ``cameraState`` for this camera (following the vehicle frame)."""
        return {"distance": round(self.distance, 2), "perspective": True,
                "phi": round(90.0 - self.depression_deg, 2), "thetaOffset": 90,
                "target": [0, 0, 0], "targetOffset": [round(self.target_x, 2), 0, 0],
                "targetOrientation": [0, 0, 0, 1], "fovy": self.fovy_deg, "near": 0.5,
                "far": 5000}


def view_range(profile: Profile) -> float:
    """How far ahead (m) the view must reach: the largest sensor range of the profile (fov
    range), at least :data:`MIN_RANGE_M`."""
    ranges = [s.fov_range for s in profile.sensors.values() if s.fov_range is not None]
    return max([MIN_RANGE_M, *ranges])


def chase_camera() -> ViewCamera:
    """The chase view's camera (:data:`CHASE_DEPRESSION_DEG`, :data:`CHASE_TARGET_M`,
    :data:`CHASE_DISTANCE_M`) on its smallest panel (:data:`CHASE_PANEL`)."""
    a = math.radians(CHASE_DEPRESSION_DEG)
    eye_z = CHASE_DISTANCE_M * math.sin(a)
    return ViewCamera(CHASE_TARGET_M - CHASE_DISTANCE_M * math.cos(a), eye_z,
                      depression_deg=CHASE_DEPRESSION_DEG, height_px=CHASE_PANEL[0],
                      aspect=CHASE_PANEL[1])


@lru_cache(maxsize=16)
def camera_for(range_m: float) -> ViewCamera:
    """The range view's camera, whose view reaches from :data:`BEHIND_M` behind the origin
    (bottom edge) to ``range_m`` and a little beyond (top edge), on its smallest panel
    (:data:`RANGE_PANEL`)."""
    a = math.radians(DEPRESSION_DEG)
    half = math.radians(FOVY_DEG) / 2
    low, high = math.tan(a + half), math.tan(a - half)  # slopes of the bottom and top rays
    far = range_m * (1 + BEYOND)
    # eye at (-b, h): h = low * (b - BEHIND_M) = high * (b + far)
    b = (high * far + low * BEHIND_M) / (low - high)
    return ViewCamera(-b, high * (b + far))


#: The generated layouts' 3D views, by name: each has its own labels (``/scene/labels/<view>``).
VIEWS = ("chase", "range")


def view_cameras(profile: Profile) -> dict[str, ViewCamera]:
    """Each view's camera for ``profile`` (:data:`VIEWS`)."""
    return {"chase": chase_camera(), "range": camera_for(view_range(profile))}
