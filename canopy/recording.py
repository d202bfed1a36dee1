"""An ``.mcap`` recording of a run that Foxglove opens: poses, images, map points, map lines, stats.

Every message is JSON (``message_encoding="json"``) under a JSON Schema
(``encoding="jsonschema"``) named after Foxglove's well-known schemas, so the
3D, Image and Plot panels understand them without any plug-in:

============================  ===========================  ========================================
topic (default)               schema                       content
============================  ===========================  ========================================
``/camera/pose``              ``foxglove.PoseInFrame``     T_world_cam, expressed in ``world``
``/tf``                       ``foxglove.FrameTransform``  ``world`` → ``camera`` (same pose)
``/camera/left/image``        ``foxglove.CompressedImage`` PNG (lossless, default) or JPEG
``/map/points``               ``foxglove.PointCloud``      packed little-endian float32 x, y, z
``/map/lines``                ``foxglove.SceneUpdate``     one entity, one LinePrimitive LINE_LIST
``/stats/<actor>``            ``canopy.ActorStats``        a flat JSON object per stats message
============================  ===========================  ========================================

The schema texts below are the subset of Foxglove's published JSON Schemas
(github.com/foxglove/schemas, ``schemas/jsonschema``) for the fields written
here, written out by hand: same titles, field names, enum values (NumericType
FLOAT32 = 7, LineType LINE_LIST = 2) and base64 ``bytes`` fields. Enums are
written as integers, times as ``{"sec", "nsec"}``, as Foxglove's JSON expects.

Log and publish time of every message is the dataset time of what it shows,
in nanoseconds (``stamp_s`` must be finite and >= 0). Messages may be added out
of time order; readers sort by log time.

Crash behaviour. ``close()`` (also on ``with`` exit) writes the summary section
(indexes, statistics). A process killed with SIGKILL cannot do that: the file
then has no summary or footer, and whatever was buffered since the last flush
is lost. The writer is flushed (the open chunk ended and written out) on the
first write ``flush_period_s`` (default 1 s) after the previous flush, and a
caller that goes idle can call ``flush()`` when ``seconds_to_flush()`` reaches
0 (the recorder actor does), so such a file still holds everything up to
about the last second. MCAP readers can read it
linearly: ``read_messages`` below does (it stops cleanly at a cut-off tail);
``mcap.reader.NonSeekingReader`` does too (``make_reader`` does not: it
looks for the footer); ``mcap recover in.mcap -o out.mcap`` (the MCAP CLI)
rewrites it with a summary. Foxglove (and its fork Lichtblick) falls back to loading an unindexed file
whole into memory: fine for short runs; for long ones or a cut-off tail, run
``mcap recover`` first.
"""
from __future__ import annotations

import base64
import json
import math
import re
import time
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
from mcap.reader import NonSeekingReader
from mcap.writer import CompressionType, Writer

from shared.errors import InputError
from canopy.report import to_jsonable
from shared.geometry import rot_to_quat_wxyz

LIBRARY = "canopy-slam recorder"

POSE_TOPIC = "/camera/pose"
TF_TOPIC = "/tf"
IMAGE_TOPIC = "/camera/left/image"
POINTS_TOPIC = "/map/points"
LINES_TOPIC = "/map/lines"
STATS_PREFIX = "/stats/"

WORLD_FRAME = "world"
CAMERA_FRAME = "camera"

NUMERIC_FLOAT32 = 7   # foxglove.NumericType.FLOAT32
LINE_LIST = 2         # foxglove.LineType.LINE_LIST

# --- JSON Schemas (subset of Foxglove's, field names and enum values unchanged) -----------------

_TIME = {"type": "object", "title": "time",
         "properties": {"sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}
_VECTOR3 = {"title": "foxglove.Vector3", "type": "object",
            "properties": {k: {"type": "number"} for k in "xyz"}}
_POINT3 = {"title": "foxglove.Point3", "type": "object",
           "properties": {k: {"type": "number"} for k in "xyz"}}
_QUATERNION = {"title": "foxglove.Quaternion", "type": "object",
               "properties": {k: {"type": "number"} for k in "xyzw"}}
_POSE = {"title": "foxglove.Pose", "type": "object",
         "properties": {"position": _VECTOR3, "orientation": _QUATERNION}}
_COLOR = {"title": "foxglove.Color", "type": "object",
          "properties": {k: {"type": "number"} for k in "rgba"}}
_BYTES = {"type": "string", "contentEncoding": "base64"}
_NUMERIC_TYPE = {"title": "foxglove.NumericType", "oneOf": [
    {"title": t, "const": i} for i, t in enumerate(
        ("UNKNOWN", "UINT8", "INT8", "UINT16", "INT16", "UINT32", "INT32", "FLOAT32", "FLOAT64"))]}
_LINE_TYPE = {"title": "foxglove.LineType", "oneOf": [
    {"title": "LINE_STRIP", "const": 0}, {"title": "LINE_LOOP", "const": 1}, {"title": "LINE_LIST", "const": 2}]}


def _schema(title: str, description: str, properties: dict) -> dict:
    return {"title": title, "description": description, "type": "object", "properties": properties}


_LINE_PRIMITIVE = {"title": "foxglove.LinePrimitive", "type": "object", "properties": {
    "type": _LINE_TYPE, "pose": _POSE, "thickness": {"type": "number"},
    "scale_invariant": {"type": "boolean"}, "points": {"type": "array", "items": _POINT3},
    "color": _COLOR, "colors": {"type": "array", "items": _COLOR},
    "indices": {"type": "array", "items": {"type": "integer", "minimum": 0}}}}
_SCENE_ENTITY = {"title": "foxglove.SceneEntity", "type": "object", "properties": {
    "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
    "lifetime": {"type": "object", "title": "duration",
                 "properties": {"sec": {"type": "integer"},
                                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}},
    "frame_locked": {"type": "boolean"},
    "metadata": {"type": "array", "items": {"title": "foxglove.KeyValuePair", "type": "object", "properties": {
        "key": {"type": "string"}, "value": {"type": "string"}}}},
    "lines": {"type": "array", "items": _LINE_PRIMITIVE}}}

_SCENE_ENTITY_DELETION = {"title": "foxglove.SceneEntityDeletion", "type": "object", "properties": {
    "timestamp": _TIME, "id": {"type": "string"},
    "type": {"title": "foxglove.SceneEntityDeletionType",
             "oneOf": [{"title": "MATCHING_ID", "const": 0}, {"title": "ALL", "const": 1}]}}}

SCHEMAS: dict[str, dict] = {
    "foxglove.PoseInFrame": _schema(
        "foxglove.PoseInFrame", "A timestamped pose for an object or reference frame in 3D space",
        {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE}),
    "foxglove.FrameTransform": _schema(
        "foxglove.FrameTransform", "A transform between two reference frames in 3D space",
        {"timestamp": _TIME, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
         "translation": _VECTOR3, "rotation": _QUATERNION}),
    "foxglove.CompressedImage": _schema(
        "foxglove.CompressedImage", "A compressed image",
        {"timestamp": _TIME, "frame_id": {"type": "string"}, "data": _BYTES, "format": {"type": "string"}}),
    "foxglove.PointCloud": _schema(
        "foxglove.PointCloud", "A collection of N-dimensional points",
        {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE,
         "point_stride": {"type": "integer", "minimum": 0},
         "fields": {"type": "array", "items": {"title": "foxglove.PackedElementField", "type": "object",
                                               "properties": {"name": {"type": "string"},
                                                              "offset": {"type": "integer", "minimum": 0},
                                                              "type": _NUMERIC_TYPE}}},
         "data": _BYTES}),
    "foxglove.SceneUpdate": _schema(
        "foxglove.SceneUpdate", "An update to the entities displayed in a 3D scene",
        {"deletions": {"type": "array", "items": _SCENE_ENTITY_DELETION},
         "entities": {"type": "array", "items": _SCENE_ENTITY}}),
    "canopy.ActorStats": {
        "title": "canopy.ActorStats",
        "description": "Per-actor statistics of a Canopy SLAM run (latency in ms, CPU %, RSS in MiB, counters)",
        "type": "object",
        "properties": {"timestamp": _TIME, "actor": {"type": "string"}},
        "additionalProperties": True},
}

_IDENTITY_POSE = {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                  "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
_ACTOR_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")
_TOPIC = re.compile(r"^/[A-Za-z0-9_./-]*$")


# --- helpers ------------------------------------------------------------------------------------

def stamp_to_ns(stamp_s: float, what: str = "stamp") -> int:
    """Dataset time in seconds → integer nanoseconds (finite, >= 0)."""
    try:
        s = float(stamp_s)
    except (TypeError, ValueError):
        raise InputError(what, f"timestamp must be a number of seconds, got {stamp_s!r}") from None
    if not math.isfinite(s) or s < 0:
        raise InputError(what, f"timestamp must be finite and >= 0 s, got {stamp_s!r}")
    return int(round(s * 1e9))


def _time(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _check_topic(topic: str) -> str:
    if not isinstance(topic, str) or not _TOPIC.match(topic) or len(topic) < 2:
        raise InputError("topic", f"topic must look like '/a/b' (letters, digits, _ . - /), got {topic!r}")
    return topic


def _pose_json(T: np.ndarray) -> tuple[dict, dict]:
    q = rot_to_quat_wxyz(T[:3, :3])  # (w, x, y, z)
    t = T[:3, 3]
    return ({"x": float(t[0]), "y": float(t[1]), "z": float(t[2])},
            {"x": float(q[1]), "y": float(q[2]), "z": float(q[3]), "w": float(q[0])})


def check_output_path(path: str | Path) -> Path:
    """Validate a recording path before a run starts: an ``.mcap`` name, not a folder, and a
    file there can be created (tried for real; the parent folder is created, the test file
    removed again). Raises ``InputError`` naming the path."""
    p = Path(path)
    if p.suffix.lower() != ".mcap":
        raise InputError(p, "a recording must be an .mcap file")
    if p.is_dir():
        raise InputError(p, "is a folder; give a file name ending in .mcap")
    existed = p.exists()
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        with open(p, "ab"):
            pass
    except (FileExistsError, NotADirectoryError):
        raise InputError(p, "cannot create a file there (a parent is not a folder)") from None
    except OSError as exc:
        raise InputError(p, f"cannot create the recording: {exc.strerror or exc}") from None
    if not existed:
        p.unlink()
    return p


# --- writer -------------------------------------------------------------------------------------

class McapRecorder:
    """Writes Foxglove-readable JSON messages to an ``.mcap`` file. Use as a context manager or
    call ``close()`` (idempotent) so the summary section is written.

    ``image_format``: ``"png"`` (lossless, default) or ``"jpeg"`` (``jpeg_quality``).
    ``flush_period_s``: at most this long between writer flushes (bounds what a SIGKILL loses).
    """

    def __init__(self, path: str | Path, image_format: str = "png", jpeg_quality: int = 90,
                 chunk_size: int = 1 << 20, compression: str = "zstd", flush_period_s: float = 1.0):
        if image_format not in ("png", "jpeg"):
            raise InputError("image_format", f"must be 'png' or 'jpeg', got {image_format!r}")
        if not 1 <= int(jpeg_quality) <= 100:
            raise InputError("jpeg_quality", f"must be 1..100, got {jpeg_quality!r}")
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in comp:
            raise InputError("compression", f"must be one of {sorted(comp)}, got {compression!r}")
        self.path = check_output_path(path)
        self.image_format = image_format
        self.jpeg_quality = int(jpeg_quality)
        self.flush_period_s = float(flush_period_s)
        try:
            self._file = open(self.path, "wb")
        except OSError as exc:
            raise InputError(self.path, f"cannot create the recording: {exc.strerror or exc}") from None
        self._writer = Writer(self._file, chunk_size=int(chunk_size), compression=comp[compression])
        self._writer.start(profile="", library=LIBRARY)
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}   # topic -> (channel id, schema name)
        self.counts: dict[str, int] = {}                  # messages written per topic
        self._last_flush = time.monotonic()
        self._dirty = False                               # written since the last flush
        self.closed = False

    # -- plumbing --------------------------------------------------------------------------------
    def _channel(self, topic: str, schema_name: str) -> int:
        found = self._channels.get(topic)
        if found is not None:
            if found[1] != schema_name:
                raise InputError(topic, f"topic already carries {found[1]}, cannot also carry {schema_name}")
            return found[0]
        if schema_name not in self._schema_ids:
            data = json.dumps(SCHEMAS[schema_name], separators=(",", ":")).encode()
            self._schema_ids[schema_name] = self._writer.register_schema(schema_name, "jsonschema", data)
        cid = self._writer.register_channel(topic, "json", self._schema_ids[schema_name])
        self._channels[topic] = (cid, schema_name)
        return cid

    def _write(self, topic: str, schema_name: str, ns: int, payload: dict) -> None:
        if self.closed:
            raise InputError(self.path, "recording is closed")
        cid = self._channel(topic, schema_name)
        data = json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()
        self._writer.add_message(cid, log_time=ns, data=data, publish_time=ns)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self._dirty = True
        if time.monotonic() - self._last_flush >= self.flush_period_s:
            self.flush()

    def flush(self) -> None:
        """Put everything written so far on disk (ends the current chunk; no fsync)."""
        if self.closed:
            return
        if hasattr(self._writer, "flush"):   # mcap >= 1.6: closes the open chunk too
            self._writer.flush()
        self._file.flush()
        self._last_flush = time.monotonic()
        self._dirty = False

    def seconds_to_flush(self) -> float | None:
        """Seconds until unflushed data is due to be flushed (<= 0: now); None if nothing is."""
        if self.closed or not self._dirty:
            return None
        return self._last_flush + self.flush_period_s - time.monotonic()

    # -- messages --------------------------------------------------------------------------------
    def add_pose(self, stamp_s: float, T_world_cam, frame_id: str = CAMERA_FRAME,
                 parent_frame_id: str = WORLD_FRAME, topic: str = POSE_TOPIC) -> None:
        """Camera pose ``T_world_cam`` (4x4, camera → world). Writes a PoseInFrame on ``topic``
        (expressed in ``parent_frame_id``) and a FrameTransform ``parent_frame_id`` → ``frame_id``
        on ``/tf``, so the 3D panel can follow the camera and images attach to it."""
        ns = stamp_to_ns(stamp_s, "pose")
        T = np.asarray(T_world_cam)
        if T.shape != (4, 4) or not np.issubdtype(T.dtype, np.number):
            raise InputError("pose", f"T_world_cam must be a numeric (4, 4) array, got {T.dtype} {T.shape}")
        T = T.astype(np.float64)
        if not np.isfinite(T).all():
            raise InputError("pose", f"T_world_cam at {stamp_s} s has NaN or inf entries")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
            raise InputError("pose", f"T_world_cam at {stamp_s} s does not hold a rotation matrix")
        for name, value in (("frame_id", frame_id), ("parent_frame_id", parent_frame_id)):
            if not isinstance(value, str) or not value:
                raise InputError("pose", f"{name} must be a non-empty string, got {value!r}")
        position, orientation = _pose_json(T)
        self._write(_check_topic(topic), "foxglove.PoseInFrame", ns,
                    {"timestamp": _time(ns), "frame_id": parent_frame_id,
                     "pose": {"position": position, "orientation": orientation}})
        self._write(TF_TOPIC, "foxglove.FrameTransform", ns,
                    {"timestamp": _time(ns), "parent_frame_id": parent_frame_id, "child_frame_id": frame_id,
                     "translation": position, "rotation": orientation})

    def add_image(self, stamp_s: float, image, topic: str = IMAGE_TOPIC, frame_id: str = CAMERA_FRAME) -> None:
        """A uint8 grey (H, W) image (BGR (H, W, 3) also accepted), compressed to PNG or JPEG."""
        ns = stamp_to_ns(stamp_s, "image")
        img = image
        if not isinstance(img, np.ndarray):
            raise InputError("image", f"expected a numpy array, got {type(image).__name__}")
        if img.dtype != np.uint8:
            raise InputError("image", f"expected uint8 pixels, got {img.dtype}")
        if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)) or img.size == 0:
            raise InputError("image", f"expected a non-empty (H, W) grey or (H, W, 3) image, got {img.shape}")
        if self.image_format == "png":
            ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])  # fast; still lossless
        else:
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise InputError("image", f"OpenCV could not encode a {img.shape} image as {self.image_format}")
        self._write(_check_topic(topic), "foxglove.CompressedImage", ns,
                    {"timestamp": _time(ns), "frame_id": frame_id,
                     "data": base64.b64encode(buf.tobytes()).decode("ascii"), "format": self.image_format})

    def add_point_cloud(self, stamp_s: float, points, topic: str = POINTS_TOPIC,
                        frame_id: str = WORLD_FRAME) -> int:
        """Map points (N, 3) in ``frame_id`` as packed little-endian float32 x, y, z (stride 12).
        Rows with NaN/inf are left out; returns the number of points written."""
        ns = stamp_to_ns(stamp_s, "point cloud")
        pts = np.asarray(points)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError("point cloud", f"points must have shape (N, 3), got {pts.shape}")
        if not (np.issubdtype(pts.dtype, np.floating) or np.issubdtype(pts.dtype, np.integer)):
            raise InputError("point cloud", f"points must be numbers, got dtype {pts.dtype}")
        pts = pts.astype("<f4")
        pts = np.ascontiguousarray(pts[np.isfinite(pts).all(axis=1)])
        self._write(_check_topic(topic), "foxglove.PointCloud", ns,
                    {"timestamp": _time(ns), "frame_id": frame_id, "pose": _IDENTITY_POSE, "point_stride": 12,
                     "fields": [{"name": n, "offset": 4 * i, "type": NUMERIC_FLOAT32} for i, n in enumerate("xyz")],
                     "data": base64.b64encode(pts.tobytes()).decode("ascii")})
        return len(pts)

    def add_lines(self, stamp_s: float, segments, topic: str = LINES_TOPIC, frame_id: str = WORLD_FRAME,
                  entity_id: str = "map_lines", color=(1.0, 0.55, 0.0, 1.0), thickness_px: float = 2.0) -> int:
        """Line segments (L, 2, 3) (endpoints A, B) as one SceneEntity with a LINE_LIST primitive.
        The entity id is fixed, so each update replaces the previous map. Segments with NaN/inf are
        left out; returns the number written."""
        ns = stamp_to_ns(stamp_s, "lines")
        seg = np.asarray(segments)
        if seg.ndim != 3 or seg.shape[1:] != (2, 3):
            raise InputError("lines", f"segments must have shape (L, 2, 3), got {seg.shape}")
        if not (np.issubdtype(seg.dtype, np.floating) or np.issubdtype(seg.dtype, np.integer)):
            raise InputError("lines", f"segments must be numbers, got dtype {seg.dtype}")
        seg = seg.astype(np.float64)
        seg = seg[np.isfinite(seg).all(axis=(1, 2))]
        pts = [{"x": float(x), "y": float(y), "z": float(z)} for x, y, z in seg.reshape(-1, 3)]
        r, g, b, a = (float(c) for c in color)
        entity = {"timestamp": _time(ns), "frame_id": frame_id, "id": entity_id,
                  "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": [],
                  "lines": [{"type": LINE_LIST, "pose": _IDENTITY_POSE, "thickness": float(thickness_px),
                             "scale_invariant": True, "points": pts, "color": {"r": r, "g": g, "b": b, "a": a},
                             "colors": [], "indices": []}]}
        self._write(_check_topic(topic), "foxglove.SceneUpdate", ns, {"deletions": [], "entities": [entity]})
        return len(seg)

    def add_stats(self, stamp_s: float, actor: str, values: dict) -> None:
        """One JSON object on ``/stats/<actor>``: ``{"timestamp", "actor", **values}``; numpy values
        become plain numbers/lists, NaN and inf become null."""
        ns = stamp_to_ns(stamp_s, "stats")
        if not isinstance(actor, str) or not _ACTOR_NAME.match(actor):
            raise InputError("stats", f"actor name must be letters, digits, _ . -; got {actor!r}")
        if not isinstance(values, dict):
            raise InputError("stats", f"values for {actor!r} must be a dict, got {type(values).__name__}")
        body = to_jsonable(values)
        body.pop("timestamp", None)
        body.pop("actor", None)
        self._write(STATS_PREFIX + actor, "canopy.ActorStats", ns, {"timestamp": _time(ns), "actor": actor, **body})

    # -- lifetime --------------------------------------------------------------------------------
    def close(self) -> None:
        """Write the summary section (indexes, statistics) and close the file. Idempotent."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()

    def __enter__(self) -> "McapRecorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- reading back -------------------------------------------------------------------------------

def read_messages(path: str | Path, topics: list[str] | None = None) -> Iterator[tuple[str, str, int, dict]]:
    """Yield ``(topic, schema name, log_time ns, decoded JSON)`` in file order.

    Reads linearly, so it also works on a recording whose writer was killed before ``close()``
    (no summary, possibly a cut-off last record): it stops at the first incomplete record.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "recording not found")
    with open(p, "rb") as f:
        it = NonSeekingReader(f).iter_messages(topics=topics, log_time_order=False)
        while True:
            try:
                schema, channel, message = next(it)
            except StopIteration:
                return
            except Exception:  # noqa: BLE001 - McapError, struct.error, zstd errors...
                return  # the cut-off tail of a recording whose writer was killed
            yield channel.topic, schema.name if schema else "", message.log_time, json.loads(message.data)


def recording_is_finished(path: str | Path) -> bool:
    """True when mcap's seeking reader opens the file and finds its summary section."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            return make_reader(f).get_summary() is not None
    except Exception:  # noqa: BLE001 - McapError, RecordLengthLimitExceeded, struct.error, ...
        return False


def repair_recording(path: str | Path) -> int | None:
    """Finish a recording whose writer died (no summary, maybe a cut-off last record).

    The readable messages are copied, in file order, into a new file with a summary section that
    replaces the broken one atomically. Returns the number of messages kept, or None when the
    file was already finished (left untouched).
    """
    import os

    p = Path(path)
    if recording_is_finished(p):
        return None
    tmp = p.with_name(p.name + ".repair")
    kept = 0
    with open(p, "rb") as src, open(tmp, "wb") as dst:
        writer = Writer(dst, compression=CompressionType.ZSTD)
        writer.start(profile="", library=LIBRARY)
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        it = NonSeekingReader(src).iter_messages(log_time_order=False)
        while True:
            try:
                schema, channel, message = next(it)
            except StopIteration:
                break
            except Exception:  # noqa: BLE001 - the cut-off tail: keep everything before it
                break
            if schema is not None and schema.id not in schema_ids:
                schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channel_ids:
                channel_ids[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schema_ids.get(channel.schema_id, 0),
                    metadata=dict(channel.metadata))
            writer.add_message(channel_ids[channel.id], log_time=message.log_time, data=message.data,
                               publish_time=message.publish_time, sequence=message.sequence)
            kept += 1
        writer.finish()
    os.replace(tmp, p)
    return kept
