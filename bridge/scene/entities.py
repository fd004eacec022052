"""What the scene draws: pure functions from the world to one ``foxglove.SceneUpdate`` per
category, in the Tank Viz look (an orange-brown ego box, green camera lanes, magenta steering
lanes, blue radar and white camera balls, red track discs, a green lead box, yellow pedestrian
cylinders, the MIO check), each object's label laid out per view (``labels/<view>``:
:mod:`bridge.scene.labels`). Every visible field is set (a protobuf default is invisible in
Foxglove); the scene tick's entities are encoded with :mod:`bridge.scene.wire`.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache, partial

from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.CylinderPrimitive_pb2 import CylinderPrimitive
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneEntityDeletion_pb2 import SceneEntityDeletion
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.duration_pb2 import Duration

from bridge.frame import NS, timestamp
from bridge.profile.model import ObjectClass, Profile, SensorKind, Vehicle
from bridge.protowire import field
from bridge.scene.camera import MIN_MARK_PX, ViewCamera, camera_for, view_cameras, view_range
from bridge.scene.labels import Block, Label, lay_out
from bridge.scene.places import (
    CLASS_LABELS,
    LABEL_OF_VALUE,
    NO_SHARED_PLACES,
    Drawn,
    SharedPlaces,
    drawn_objects,
    place_notes,
    shared_places,
)
from bridge.scene.wire import (
    CUBES_TAG,
    CYLINDERS_TAG,
    ID_TAG,
    IDENTITY,
    LINES_TAG,
    ORIENTATION,
    POINTS_TAG,
    POSE_HEAD,
    TEXT_STRING_TAG,
    TEXTS_TAG,
    VECTOR,
    WireEntity,
    line_points,
    metadata,
    metadata_key,
    scene_update,
    sphere_parts,
    stamp_field,
    without,
)
from bridge.topics import VEHICLE_FRAME, scene_topic
from bridge.world.model import LaneCurve, LaneModel, MioCheck, World
from bridge.world.observe import ObjectObservation

RGBA = tuple[float, float, float, float]
EGO_COLOR: RGBA = (0.72, 0.42, 0.16, 1.0)  # orange-brown
CAMERA_LANE_COLOR: RGBA = (0.0, 0.9, 0.1, 1.0)  # green
NEIGHBOUR_LANE_COLOR: RGBA = (0.0, 0.9, 0.1, 0.55)
STEERING_LANE_COLOR: RGBA = (1.0, 0.0, 1.0, 1.0)  # magenta
RADAR_COLOR: RGBA = (0.1, 0.35, 1.0, 1.0)  # blue
CAMERA_COLOR: RGBA = (1.0, 1.0, 1.0, 1.0)  # white
TRACK_COLOR: RGBA = (1.0, 0.1, 0.1, 1.0)  # red
LEAD_COLOR: RGBA = (0.0, 0.85, 0.2, 0.55)  # green, see-through so the track inside shows
PEDESTRIAN_COLOR: RGBA = (1.0, 0.85, 0.0, 1.0)  # yellow
MIO_COLOR: RGBA = (1.0, 0.55, 0.0, 1.0)  # orange
TEXT_COLOR: RGBA = (1.0, 1.0, 1.0, 1.0)
LEADER_COLOR: RGBA = (0.8, 0.8, 0.8, 0.8)  # the thin line from an object to its moved label
LEADER_PX = 1.0

DETECTION_SIZE = 0.5  # m, sphere diameter
OBJECT_Z = 0.5  # m, height of the centre of every object's marker
# A track is a flat red disc (a squashed sphere) around the object's centre: a detection at the
# same place (a ball of DETECTION_SIZE) stands out of it above and below, in its own colour.
TRACK_SIZE = 1.1  # m, disc diameter
TRACK_HEIGHT = 0.15  # m, disc thickness
LEAD_BOX = (4.5, 1.9, 1.5)  # m
LANE_THICKNESS = 0.15  # m
FONT_SIZE = 14.0  # px (scale invariant)
LANE_Z = 0.05  # m, lane lines lie just above the ground


def duration(seconds: float) -> Duration:
    ns = round(seconds * NS)
    return Duration(seconds=ns // NS, nanos=ns % NS)


_stamp = lru_cache(maxsize=4)(timestamp)
_lifetime = lru_cache(maxsize=16)(duration)


def color(rgba: RGBA) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


_color = lru_cache(maxsize=64)(color)


def pose(x: float, y: float, z: float) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=IDENTITY)


def set_pose(target: Pose, x: float, y: float, z: float) -> None:
    position = target.position
    position.x, position.y, position.z = x, y, z
    target.orientation.CopyFrom(IDENTITY)


def text(x: float, y: float, z: float, words: str) -> TextPrimitive:
    return TextPrimitive(pose=pose(x, y, z), billboard=True, font_size=FONT_SIZE,
                         scale_invariant=True, color=_color(TEXT_COLOR), text=words)


def add_text(e: SceneEntity, x: float, y: float, z: float, words: str) -> None:
    label = e.texts.add(billboard=True, font_size=FONT_SIZE, scale_invariant=True, text=words)
    set_pose(label.pose, x, y, z)
    label.color.CopyFrom(_color(TEXT_COLOR))


def entity(t_ns: int, entity_id: str, lifetime_s: float) -> SceneEntity:
    e = SceneEntity(frame_id=VEHICLE_FRAME, id=entity_id, frame_locked=True)
    e.timestamp.CopyFrom(_stamp(t_ns))
    e.lifetime.CopyFrom(_lifetime(lifetime_s))
    return e


def _template(entity_id: str, lifetime_s: float) -> SceneEntity:
    e = entity(0, entity_id, lifetime_s)
    e.ClearField("timestamp")
    return e


@lru_cache(maxsize=4)
def _ego_template(v: Vehicle) -> SceneEntity:
    e = _template("ego", 0.0)
    e.cubes.append(CubePrimitive(pose=pose(v.box_centre_x, 0.0, v.height_m / 2),
                                 size=Vector3(x=v.length_m, y=v.width_m, z=v.height_m),
                                 color=color(EGO_COLOR)))
    return e


@lru_cache(maxsize=64)
def _lane_template(name: str, rgba: RGBA, source: str) -> SceneEntity:
    """A lane line's entity without points and timestamp. Never changed, only copied."""
    e = _template(f"lane-{name}", 0.0)
    e.lines.add(type=LinePrimitive.LINE_STRIP, pose=pose(0, 0, 0), thickness=LANE_THICKNESS,
                scale_invariant=False, color=color(rgba))
    e.metadata.add(key="source", value=source)
    return e


def _lane_color(line: LaneCurve, source: str) -> RGBA:
    """Steering lanes in their colour, camera lanes in theirs (the next lanes lighter)."""
    if source == "steering":
        return STEERING_LANE_COLOR
    return NEIGHBOUR_LANE_COLOR if line.name.startswith("next") else CAMERA_LANE_COLOR


@lru_cache(maxsize=4)
def _ego_bytes(v: Vehicle) -> bytes:
    data: bytes = _ego_template(v).SerializeToString()
    return data


#: Each lane line's entity as wire bytes (all but its timestamp) by (id of the LaneCurve,
#: colour, source), with the LaneCurve itself (so that its id stays its own while it is held
#: here): made once per line.
_LANE_BYTES: dict[tuple[int, RGBA, str], tuple[LaneCurve, bytes]] = {}


@lru_cache(maxsize=64)
def _lane_parts(name: str, rgba: RGBA, source: str) -> tuple[bytes, bytes]:
    """A lane line's template (:func:`_lane_template`) as wire bytes: the entity without its
    line, and the line without its points."""
    template = _lane_template(name, rgba, source)
    return without(template, "lines"), template.lines[0].SerializeToString()


def _lane_bytes(line: LaneCurve, rgba: RGBA, source: str) -> bytes:
    key = (id(line), rgba, source)
    held = _LANE_BYTES.get(key)
    if held is not None and held[0] is line:
        return held[1]
    head, primitive = _lane_parts(line.name, rgba, source)
    data = head + field(LINES_TAG, primitive + line_points(line.points, LANE_Z))
    if len(_LANE_BYTES) >= 64:  # the lines of a few ticks are enough to hold
        _LANE_BYTES.clear()
    _LANE_BYTES[key] = (line, data)
    return data


def lane_entities(into: list[WireEntity], lanes: LaneModel, t_ns: int) -> None:
    """The lane lines, each an entity ``lane-<name>`` (added to ``into``) with its source in
    its metadata."""
    stamp = stamp_field(t_ns)
    source = lanes.source
    for line in lanes.lines:
        into.append(WireEntity(f"lane-{line.name}",
                               [_lane_bytes(line, _lane_color(line, source), source), stamp]))


@dataclass(frozen=True)
class _ObjectParts:
    """What every object entity of one kind, role and class shares, as wire bytes."""

    template: bytes  # frame, lifetime, class metadata
    head: bytes  # the mark's field up to its position (SpherePrimitive.pose.position)
    tail: bytes  # after its size (the colour)
    size: float  # the mark's base diameter
    height: float  # and height


@lru_cache(maxsize=256)
def _object_parts(kind: SensorKind, lifetime_s: float, object_class: ObjectClass,
                  track: bool) -> _ObjectParts:
    e = _template("", lifetime_s)
    e.metadata.add(key="class", value=object_class.value)
    if track:
        size, height, rgba = TRACK_SIZE, TRACK_HEIGHT, TRACK_COLOR
    else:
        size = height = DETECTION_SIZE
        rgba = RADAR_COLOR if kind is SensorKind.RADAR else CAMERA_COLOR
    head, tail = sphere_parts(color(rgba))
    return _ObjectParts(e.SerializeToString(), head, tail, size, height)


def _pedestrian(x: float, y: float) -> bytes:
    """A pedestrian's tall yellow cylinder at (x, y), as a SceneEntity's field."""
    return field(CYLINDERS_TAG, CylinderPrimitive(
        pose=pose(x, y, 0.9), size=Vector3(x=0.6, y=0.6, z=1.8), bottom_scale=1.0,
        top_scale=1.0, color=_color(PEDESTRIAN_COLOR)).SerializeToString())


#: ``Label`` of a tuple of its fields: the very object ``Label(*fields)`` makes, without its
#: Python-level ``__new__`` (a few dozen a tick)
_label = partial(tuple.__new__, Label)

#: The MIO check's reason is drawn in lines of at most this many characters.
MIO_LINE_CHARS = 40
#: Label priorities (lower first), then nearer first: see bridge.scene.labels.
MIO_FIRST, LEAD_NEXT, TRACKS_NEXT, DETECTIONS_LAST = 0, 1, 2, 3


#: The metadata keys of an object's entity and of the lead's.
_IDS_KEY, _PLACE_KEY, _VX_KEY, _LABEL_KEY = (
    metadata_key(k) for k in ("ids", "place", "vx", "label"))

#: What names an object drawn (its group and ids): its entity's id, its ids as a label names
#: them (Drawn.id_text), and the entity's id field and "ids" metadata as wire bytes.
_Named = tuple[str, str, bytes, bytes]
_NAMES: dict[tuple[str, tuple[int, ...]], _Named] = {}


def _name(group: str, ids: tuple[int, ...]) -> _Named:
    """What names the object ``ids`` of ``group`` (held in _NAMES, for the next ticks)."""
    entity_id = f"{group}-{ids[0]}"
    id_text = "/".join(str(i) for i in ids)
    named = (entity_id, id_text, field(ID_TAG, entity_id.encode()),
             metadata(_IDS_KEY, id_text))
    if len(_NAMES) >= 4096:  # the objects of many ticks; a drive renumbers them now and then
        _NAMES.clear()
    _NAMES[group, ids] = named
    return named


#: Numbers written with two decimals (a place, a velocity), by value: a sensor's resolution
#: makes most of them again and again. Zero (0.0 and -0.0, which == cannot tell apart, and
#: which are written apart: "0.00", "-0.00") is never held.
_HUNDREDTHS: dict[float, str] = {}


def _hundredths(value: float) -> str:
    """``f"{value:.2f}"``, held in :data:`_HUNDREDTHS` (but zero)."""
    text = f"{value:.2f}"
    if value:
        if len(_HUNDREDTHS) >= 8192:
            _HUNDREDTHS.clear()
        _HUNDREDTHS[value] = text
    return text


#: An object's "vx" metadata item as wire bytes, by the value (as :data:`_HUNDREDTHS`).
_SPEEDS: dict[float, bytes] = {}


def _speed(vx: float) -> bytes:
    """The "vx" metadata item of ``vx``, held in :data:`_SPEEDS` (but zero)."""
    item = metadata(_VX_KEY, f"{vx:.2f} m/s")
    if vx:
        if len(_SPEEDS) >= 8192:
            _SPEEDS.clear()
        _SPEEDS[vx] = item
    return item


def object_entities(into: list[WireEntity], objects: Iterable[Drawn], kind: SensorKind,
                    t_ns: int, lifetime_s: float, camera: ViewCamera, *, track: bool,
                    lead: Drawn | None = None,
                    places: SharedPlaces = NO_SHARED_PLACES) -> list[Label]:
    """Detections (radar blue, camera white balls) or tracks (red discs), each set of twins as
    one object, each mark at least MIN_MARK_PX wide from the generated camera (its size, and
    heights, grow with the distance: :meth:`ViewCamera.scale`); returns their labels to lay out
    (:func:`bridge.scene.labels.lay_out`).

    A track's label is the seed's "TrackID: n / x: … / y: …" (``2/8`` for twins), then its
    class and the notes of its place (``places``: the other classes seen there), one a line;
    the track that is ``lead`` has none (the lead's label names it). A detection's label is its
    class, where known, unless the detection is at a track's place (``places``: the track's
    block carries it). Each entity (a :class:`WireEntity`, added to ``into``) carries its
    label's text once laid out (:func:`draw_labels`); its metadata holds its ids, place and
    velocity."""
    stamp = stamp_field(t_ns)
    pack = VECTOR.pack
    hundredths, speeds = _HUNDREDTHS, _SPEEDS
    # camera.scale(x, y, DETECTION_SIZE)'s terms
    cos, sin = camera.sight
    eye_x, eye_z, focal = camera.eye_x, camera.eye_z, camera.focal_px
    covered, notes = places.covered, places.notes
    labels = []
    kinds: dict[str, _ObjectParts] = {}  # by class value (an Enum hashes slowly)
    for o in objects:
        first = o.first
        object_class = first.object_class
        value = object_class._value_
        parts = kinds.get(value)
        if parts is None:
            parts = kinds[value] = _object_parts(kind, lifetime_s, object_class, track)
        name = LABEL_OF_VALUE.get(value)  # the class's label, where it has one
        x, y = o.x, o.y
        f = max(1.0, MIN_MARK_PX / (DETECTION_SIZE * (  # camera.scale, inline
            focal / max((x - eye_x) * cos - (0.0 - eye_z) * sin, 0.1))))
        size = parts.size * f
        named = _NAMES.get((o.group, o.ids))
        if named is None:
            named = _name(o.group, o.ids)
        entity_id, id_text, id_field, ids_field = named
        x2 = hundredths.get(x) if x else None  # f"{x:.2f}", f"{y:.2f}"
        if x2 is None:
            x2 = _hundredths(x)
        y2 = hundredths.get(y) if y else None
        if y2 is None:
            y2 = _hundredths(y)
        fields = [
            parts.template, stamp, id_field,
            parts.head, pack(0x0A, 27, 0x09, x, 0x11, y, 0x19, OBJECT_Z * f), ORIENTATION,
            pack(0x12, 27, 0x09, size, 0x11, size, 0x19, parts.height * f), parts.tail,
            ids_field, metadata(_PLACE_KEY, f"x {x2} m, y {y2} m")]
        vx = first.vx
        if vx is not None:
            speed = speeds.get(vx) if vx else None
            fields.append(speed or _speed(vx))
        if object_class is ObjectClass.PEDESTRIAN:
            fields.append(_pedestrian(x, y))
        e = WireEntity(entity_id, fields, lifetime_s)
        into.append(e)
        if track:
            if o is lead:
                continue
            full = f"TrackID: {id_text}\nx: {x2}\ny: {y2}"
            if name is not None:
                full += f"\n{name}"
            if notes:
                full = "\n".join([full, *place_notes(places, o)])
            compact = f"TrackID: {id_text} \u00b7 {math.hypot(x, y):.0f} m"
            labels.append(_label((e, x, y, 1.6 * f, full, compact, compact,
                                  (TRACKS_NEXT, x))))
        elif name is not None and (o.group, o.ids[0]) not in covered:
            labels.append(_label((e, x, y, 1.1 * f, name, name, f"{o.group}: {name}",
                                  (DETECTIONS_LAST, x))))
    return labels


@lru_cache(maxsize=16)
def _lead_template(lifetime_s: float) -> SceneEntity:
    """The lead box at x = y = 0. Never changed, only copied."""
    e = _template("lead", lifetime_s)
    length, width, height = LEAD_BOX
    e.cubes.append(CubePrimitive(pose=pose(length / 2, 0.0, height / 2),
                                 size=Vector3(x=length, y=width, z=height),
                                 color=color(LEAD_COLOR)))
    return e


@lru_cache(maxsize=16)
def _lead_parts(lifetime_s: float) -> tuple[bytes, bytes]:
    """The lead's template (:func:`_lead_template`) as wire bytes: the entity without its box,
    and the box (a CubePrimitive) without its pose."""
    template = _lead_template(lifetime_s)
    return without(template, "cubes"), without(template.cubes[0], "pose")


def lead_entities(into: list[WireEntity], lead: ObjectObservation | None, t_ns: int,
                  lifetime_s: float, track: Drawn | None = None,
                  notes: Sequence[str] = ()) -> list[Label]:
    """The lead box; its label "Lead Vehicle · TrackID: n / x / y" names its ``track`` (the
    track's own label is not drawn), then the track's class and the ``notes`` of its place."""
    if lead is None:
        return []
    title = "Lead Vehicle"
    if track is not None:
        title += f" \u00b7 TrackID: {track.id_text}"
    label = f"{title}\nx: {lead.x:.2f}\ny: {lead.y:.2f}"
    if track is not None and track.first.object_class in CLASS_LABELS:
        label += f"\n{CLASS_LABELS[track.first.object_class]}"
    label = "\n".join([label, *notes])
    compact = f"Lead \u00b7 {lead.x:.0f} m" + (f" \u00b7 TrackID: {track.id_text}"
                                            if track is not None else "")
    head, rest = _lead_parts(lifetime_s)
    # the template's box moved to the lead: its centre half a box ahead of the lead's place
    place = VECTOR.pack(0x0A, 27, 0x09, lead.x + LEAD_BOX[0] / 2, 0x11, lead.y, 0x19,
                         LEAD_BOX[2] / 2)
    wire = WireEntity("lead", [
        head, stamp_field(t_ns), field(CUBES_TAG, POSE_HEAD + place + ORIENTATION + rest),
        metadata(_LABEL_KEY, label)], lifetime_s)
    into.append(wire)
    return [Label(wire, lead.x, lead.y, LEAD_BOX[2] + 1.4, label, compact, compact,
                  (LEAD_NEXT, lead.x))]


def mio_entities(into: list[WireEntity], check: MioCheck, t_ns: int,
                 lifetime_s: float) -> list[Label]:
    """Nothing when the lead is the closest in-lane track; otherwise a ring and the reason."""
    if check.ok:
        return []
    e = entity(t_ns, "mio-check", lifetime_s)
    target = check.expected or check.lead
    if target is not None:
        e.cylinders.append(CylinderPrimitive(
            pose=pose(target.x, target.y, 0.02), size=Vector3(x=3.0, y=3.0, z=0.04),
            bottom_scale=1.0, top_scale=1.0, color=color(MIO_COLOR)))
        x, y = target.x, target.y
    else:
        x, y = 5.0, 0.0
    wire = WireEntity("mio-check", [e.SerializeToString()], lifetime_s)
    into.append(wire)
    # in lines a laptop's panel holds (the reason is a sentence)
    words = "\n".join(textwrap.wrap(f"MIO CHECK: {check.reason}", MIO_LINE_CHARS))
    return [Label(wire, x, y, 3.2, words, "MIO CHECK", "MIO CHECK", (MIO_FIRST, x))]


#: A label's TextPrimitive but its pose and text (billboard, font size, scale invariance,
#: colour), as :func:`add_text` sets them.
_TEXT_REST = TextPrimitive(billboard=True, font_size=FONT_SIZE, scale_invariant=True,
                           color=color(TEXT_COLOR)).SerializeToString()


def _leader_head() -> bytes:
    """A leader line (a LinePrimitive) as wire bytes, without its points."""
    leader = LinePrimitive(type=LinePrimitive.LINE_STRIP, thickness=LEADER_PX,
                           scale_invariant=True)
    set_pose(leader.pose, 0.0, 0.0, 0.0)
    leader.color.CopyFrom(_color(LEADER_COLOR))
    data: bytes = leader.SerializeToString()
    return data


_LEADER_HEAD = _leader_head()


@lru_cache(maxsize=1024)
def _label_head(entity_id: str, lifetime_s: float) -> bytes:
    """A label entity without its timestamp, text and leader, as wire bytes."""
    data: bytes = _template(entity_id, lifetime_s).SerializeToString()
    return data


def draw_labels(into: list[WireEntity], blocks: Iterable[Block], t_ns: int) -> None:
    """Each laid-out block as an entity of its own (added to ``into``), with the id and lifetime
    of the entity it names (its ``owner``, a :class:`WireEntity`); a block moved off its place
    with a thin leader line from where its label would have stood to its edge."""
    pack = VECTOR.pack
    stamp = stamp_field(t_ns)
    for b in blocks:
        owner = b.owner
        assert isinstance(owner, WireEntity)
        parts = [_label_head(owner.id, owner.lifetime_s), stamp, field(TEXTS_TAG, b"".join((
            POSE_HEAD, pack(0x0A, 27, 0x09, b.x, 0x11, b.y, 0x19, b.z), ORIENTATION,
            _TEXT_REST, field(TEXT_STRING_TAG, b.text.encode()))))]
        if b.leader is not None:
            parts.append(field(LINES_TAG, _LEADER_HEAD + b"".join(
                [pack(POINTS_TAG, 27, 0x09, x, 0x11, y, 0x19, z) for x, y, z in b.leader])))
        into.append(WireEntity(owner.id, parts, owner.lifetime_s))


#: Each profile's transforms without their timestamps, as wire bytes (each FrameTransform's
#: fields), by the id of the profile (held with it, so that its id stays its own): built once,
#: then stamped and parsed at each tick.
_TRANSFORMS: dict[int, tuple[Profile, tuple[bytes, ...]]] = {}


def frame_transforms(profile: Profile, t_ns: int) -> FrameTransforms:
    """One transform per sensor mount, parent the vehicle frame."""
    held = _TRANSFORMS.get(id(profile))
    if held is None or held[0] is not profile:
        transforms = []
        for sensor in profile.sensors.values():
            yaw = math.radians(sensor.mount.yaw_deg)
            transforms.append(FrameTransform(
                parent_frame_id=VEHICLE_FRAME, child_frame_id=sensor.name,
                translation=Vector3(x=sensor.mount.x, y=sensor.mount.y, z=sensor.mount.z),
                rotation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
            ).SerializeToString())
        if len(_TRANSFORMS) >= 16:
            _TRANSFORMS.clear()
        held = _TRANSFORMS[id(profile)] = (profile, tuple(transforms))
    # each transform (FrameTransforms field 1) with the tick's stamp (FrameTransform field 1)
    stamp = stamp_field(t_ns)
    out: FrameTransforms = FrameTransforms.FromString(b"".join(
        [field(b"\x0a", stamp + transform) for transform in held[1]]))
    return out


@dataclass
class SceneState:
    """Entity ids sent last time per topic, so that vanished entities are deleted."""

    sent: dict[str, set[str]]


def update(topic: str, entities: Iterable[SceneEntity], t_ns: int,
           state: SceneState) -> SceneUpdate:
    """A SceneUpdate of ``entities`` that also deletes what was sent before and is gone now."""
    made = SceneUpdate(entities=entities)
    return _delete(topic, made, {e.id for e in made.entities}, t_ns, state)


def _delete(topic: str, message: SceneUpdate, ids: set[str], t_ns: int,
            state: SceneState) -> SceneUpdate:
    """``message`` (its entities' ``ids``) with deletions of what was sent on ``topic``
    before and is gone now."""
    sent = state.sent.get(topic)
    state.sent[topic] = ids
    if sent and not sent <= ids:
        stamp = timestamp(t_ns)
        message.deletions.extend(
            SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletion.MATCHING_ID, id=i)
            for i in sorted(sent - ids))
    return message


def scene_updates(world: World, lanes: LaneModel, check: MioCheck, t_ns: int,
                  state: SceneState, *, lead_track: ObjectObservation | None = None,
                  twins: Mapping[str, Mapping[int, tuple[int, ...]]] | None = None,
                  cameras: Mapping[str, ViewCamera] | None = None) -> dict[str, SceneUpdate]:
    """Every category's SceneUpdate at ``t_ns`` (category -> update).

    ``lead_track``: the track that is the lead (default: the MIO check's track, when the check
    holds); ``twins``: each group's sets of twins (:func:`bridge.world.lead.twin_sets`), drawn
    as one object; ``cameras``: the views, each of which gets its labels (``labels/<view>``);
    the range view's camera sizes the marks (default: the profile's,
    :func:`bridge.scene.camera.view_cameras`)."""
    profile = world.profile
    twins = twins or {}
    if cameras is None:
        cameras = view_cameras(profile)
    camera = cameras.get("range") or camera_for(view_range(profile))
    out: dict[str, list[WireEntity]] = {}

    def category(name: str) -> list[WireEntity]:
        out[name] = []
        return out[name]

    category("ego").append(WireEntity("ego", [_ego_bytes(profile.vehicle), stamp_field(t_ns)]))
    lane_entities(category("lanes"), lanes, t_ns)
    if lead_track is None and check.ok and check.lead is not None:
        lead_track = check.expected
    drawn = {name: drawn_objects(world.objects[name], twins.get(name, {}))
             for name in profile.groups}
    lead_drawn = None if lead_track is None else next(
        (o for o in drawn.get(lead_track.group, ()) if lead_track.object_id in o.ids), None)
    # A detection at a track's place is labelled once, in the track's block.
    places = shared_places(
        [o for name, g in profile.groups.items() if g.is_tracks
         for o in world.objects[name].values()],
        [o for name, g in profile.groups.items() if not g.is_tracks
         for o in world.objects[name].values()])
    labels: list[Label] = []
    for name, group in profile.groups.items():
        labels += object_entities(category(name), drawn[name], group.sensor.kind, t_ns,
                                  group.lifetime_s, camera, track=group.is_tracks,
                                  lead=lead_drawn, places=places)
    if profile.lead is not None:
        lead_notes = () if lead_drawn is None else place_notes(places, lead_drawn)
        labels += lead_entities(category("lead"), check.lead, t_ns, profile.lead.lifetime_s,
                                lead_drawn, lead_notes)
        labels += mio_entities(category("mio"), check, t_ns, profile.lead.lifetime_s)
    for view, view_camera in cameras.items():
        draw_labels(category(label_category(view)), lay_out(labels, view_camera), t_ns)
    return {name: _delete(_scene_topic(name), scene_update(entities),
                          {e.id for e in entities}, t_ns, state)
            for name, entities in out.items()}


_scene_topic = lru_cache(maxsize=256)(scene_topic)


def label_category(view: str) -> str:
    """The scene category of one view's labels (``labels/range``: ``/scene/labels/range``)."""
    return f"labels/{view}"
