"""Pipeline results → MAVLink messages (pure functions; the endpoint sends them).

- ``TCM_OBJECT_STATUS`` (our dialect): every tracked object of every frame, with its label
  mapped onto TCM_OBJECT_LABEL (:func:`label_id`).
- ``OBSTACLE_DISTANCE`` (common): 72 sectors of 5° around the body, BODY_FRD; what PX4's
  collision prevention and ArduPilot's MAVLink proximity backend consume. A sector holds
  the nearest object of known range that covers it; every other sector says "no
  obstacle" (max_distance + 1), because both autopilots treat silence as a fault.
- ``OBSTACLE_DISTANCE_3D`` (ardupilotmega): one per object of known range, body FRD.
- ``ADSB_VEHICLE``: a moving object as a traffic report for ArduPilot's AP_Avoidance;
  needs the object's position (range from the configured object radius) and the
  global origin of the local frame.

What each autopilot does with each message is in docs/mavlink.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence

import numpy as np

from ..core.pipeline import FrameResult, ObjectResult
from . import tcm_dialect as d

REASONS: dict[str, int] = {
    "": d.TCM_UNKNOWN_REASON_NONE,
    "warm-up": d.TCM_UNKNOWN_REASON_WARM_UP,
    "lost track": d.TCM_UNKNOWN_REASON_LOST_TRACK,
    "head-on": d.TCM_UNKNOWN_REASON_HEAD_ON,
    "no translation": d.TCM_UNKNOWN_REASON_NO_TRANSLATION,
    "small baseline": d.TCM_UNKNOWN_REASON_NO_TRANSLATION,
    "no attitude": d.TCM_UNKNOWN_REASON_NO_ATTITUDE,
    "at image border": d.TCM_UNKNOWN_REASON_IMAGE_BORDER,
}
STATES: dict[str, int] = {
    "unknown": d.TCM_OBJECT_STATE_UNKNOWN,
    "stationary": d.TCM_OBJECT_STATE_STATIONARY,
    "moving": d.TCM_OBJECT_STATE_MOVING,
}
#: Detector labels → TCM_OBJECT_LABEL, by lower-case name (COCO's classes among them);
#: "" is NONE, any other label OTHER (:func:`label_id`).
LABELS: dict[str, int] = {
    **dict.fromkeys(
        ("person", "pedestrian", "people", "human", "man", "woman", "child"),
        d.TCM_OBJECT_LABEL_PERSON,
    ),
    **dict.fromkeys(("car", "automobile"), d.TCM_OBJECT_LABEL_CAR),
    **dict.fromkeys(("truck", "van", "lorry", "pickup"), d.TCM_OBJECT_LABEL_TRUCK),
    "bus": d.TCM_OBJECT_LABEL_BUS,
    **dict.fromkeys(("motorcycle", "motorbike"), d.TCM_OBJECT_LABEL_MOTORCYCLE),
    **dict.fromkeys(("bicycle", "bike"), d.TCM_OBJECT_LABEL_BICYCLE),
    **dict.fromkeys(("train", "tram"), d.TCM_OBJECT_LABEL_TRAIN),
    **dict.fromkeys(("boat", "ship"), d.TCM_OBJECT_LABEL_BOAT),
    **dict.fromkeys(
        ("airplane", "aeroplane", "aircraft", "plane", "helicopter", "glider"),
        d.TCM_OBJECT_LABEL_AIRCRAFT,
    ),
    **dict.fromkeys(("drone", "uav", "uas", "multicopter", "quadcopter"), d.TCM_OBJECT_LABEL_DRONE),
    "bird": d.TCM_OBJECT_LABEL_BIRD,
    **dict.fromkeys(
        (
            "animal",
            "cat",
            "dog",
            "horse",
            "sheep",
            "cow",
            "elephant",
            "bear",
            "zebra",
            "giraffe",
            "deer",
        ),
        d.TCM_OBJECT_LABEL_ANIMAL,
    ),
    **dict.fromkeys(("ball", "sports ball"), d.TCM_OBJECT_LABEL_BALL),
    **dict.fromkeys(("kite", "balloon"), d.TCM_OBJECT_LABEL_KITE),
}


def label_id(label: str) -> int:
    """TCM_OBJECT_LABEL of a detector's label (case and surrounding spaces ignored)."""
    key = label.strip().lower()
    if not key:
        return int(d.TCM_OBJECT_LABEL_NONE)
    return LABELS.get(key, int(d.TCM_OBJECT_LABEL_OTHER))


SECTORS = 72
SECTOR_DEG = 5
NO_RANGE = math.nan


def body_azel_rad(bearing_body: np.ndarray) -> tuple[float, float]:
    """Azimuth (from forward towards right) and elevation (up) of an FRD bearing."""
    x, y, z = (float(c) for c in bearing_body)
    return math.atan2(y, x), math.atan2(-z, math.hypot(x, y))


def object_range_m(obj: ObjectResult, object_radius_m: float) -> float:
    """Range of an object: the sine rule for a stationary one (metric translation), else
    the configured physical radius over ``sin α`` (NaN when that radius is unknown)."""
    if obj.state == "stationary" and math.isfinite(obj.classification.range_m):
        return obj.classification.range_m
    if object_radius_m > 0 and obj.angular_radius_rad > 0:
        return object_radius_m / math.sin(obj.angular_radius_rad)
    return NO_RANGE


def ranged(
    objects: Sequence[ObjectResult], object_radius_m: float
) -> Iterator[tuple[ObjectResult, float]]:
    """``(object, range m)`` of the objects whose range is known (:func:`object_range_m`)."""
    for obj in objects:
        rng = object_range_m(obj, object_radius_m)
        if math.isfinite(rng):
            yield obj, rng


#: The meaning of our fields this companion follows (TCM_PIPELINE_HEALTH.protocol): 2 sends
#: ttc_confidence and raises collision alarms whatever the motion state (docs/mavlink.md).
PROTOCOL = 2


def confidence_pct(obj: ObjectResult, threshold: float) -> int:
    """Confidence of the motion *state*: how far the disparity is from the threshold,
    relative to it (0 when the state is unknown). Not about time to contact."""
    if obj.state == "unknown" or not math.isfinite(obj.disparity) or threshold <= 0:
        return 0
    return round(100 * min(1.0, abs(obj.disparity - threshold) / threshold))


def ttc_confidence_pct(obj: ObjectResult) -> int:
    """Confidence of ``ttc`` and ``collision_course`` (0 when there is no ttc): from the
    looming fit, whatever the state, so a head-on object can raise an alarm."""
    if not math.isfinite(obj.ttc_s):
        return 0
    return round(100 * max(0.0, min(1.0, obj.ttc_confidence)))


def object_status(
    obj: ObjectResult, time_boot_ms: int, threshold: float, camera_id: int, object_radius_m: float
) -> d.MAVLink_tcm_object_status_message:
    az, el = body_azel_rad(obj.bearing_body)
    reason = REASONS.get(obj.reason, d.TCM_UNKNOWN_REASON_UNCERTAIN)
    return d.MAVLink_tcm_object_status_message(
        time_boot_ms=time_boot_ms & 0xFFFFFFFF,
        track_id=obj.track_id & 0xFFFF,
        camera_id=camera_id,
        state=STATES[obj.state],
        reason=reason if obj.state == "unknown" else d.TCM_UNKNOWN_REASON_NONE,
        disparity=obj.disparity if obj.state != "unknown" else math.nan,
        threshold=threshold,
        ttc=obj.ttc_s,
        collision_course=int(obj.collision_course),
        azimuth=az,
        elevation=el,
        angular_radius=obj.angular_radius_rad,
        range=object_range_m(obj, object_radius_m),
        confidence=confidence_pct(obj, threshold),
        ttc_confidence=ttc_confidence_pct(obj),
        label=label_id(obj.label),
    )


def object_statuses(
    result: FrameResult,
    time_boot_ms: int,
    threshold: float,
    camera_id: int = 0,
    object_radius_m: float = 0.0,
) -> list[d.MAVLink_tcm_object_status_message]:
    return [
        object_status(o, time_boot_ms, threshold, camera_id, object_radius_m)
        for o in result.objects
    ]


def obstacle_distance(
    objects: Sequence[ObjectResult],
    time_usec: int,
    object_radius_m: float,
    min_distance_cm: int = 20,
    max_distance_cm: int = 3000,
) -> d.MAVLink_obstacle_distance_message:
    """72 × 5° sectors around the body (0 = forward, clockwise), nearest known range."""
    distances = [max_distance_cm + 1] * SECTORS
    for obj, rng in ranged(objects, object_radius_m):
        az, _ = body_azel_rad(obj.bearing_body)
        cm = int(max(min_distance_cm, min(max_distance_cm, (rng - _surface(obj, rng)) * 100)))
        half = math.degrees(obj.angular_radius_rad)
        first = math.floor((math.degrees(az) - half) / SECTOR_DEG + 0.5)
        last = math.floor((math.degrees(az) + half) / SECTOR_DEG + 0.5)
        for k in range(first, last + 1):
            i = k % SECTORS
            distances[i] = min(distances[i], cm)
    return d.MAVLink_obstacle_distance_message(
        time_usec=time_usec,
        sensor_type=d.MAV_DISTANCE_SENSOR_UNKNOWN,
        distances=distances,
        increment=SECTOR_DEG,
        min_distance=min_distance_cm,
        max_distance=max_distance_cm,
        increment_f=float(SECTOR_DEG),
        angle_offset=0.0,
        frame=d.MAV_FRAME_BODY_FRD,
    )


def _surface(obj: ObjectResult, centre_range_m: float) -> float:
    """Object radius at that range (distance from centre to the near surface)."""
    return centre_range_m * math.sin(obj.angular_radius_rad)


def obstacle_distance_3d(
    objects: Sequence[ObjectResult],
    time_boot_ms: int,
    object_radius_m: float,
    min_distance_m: float = 0.2,
    max_distance_m: float = 30.0,
) -> list[d.MAVLink_obstacle_distance_3d_message]:
    out = []
    for obj, rng in ranged(objects, object_radius_m):
        x, y, z = (float(c) * rng for c in obj.bearing_body)
        out.append(
            d.MAVLink_obstacle_distance_3d_message(
                time_boot_ms=time_boot_ms & 0xFFFFFFFF,
                sensor_type=d.MAV_DISTANCE_SENSOR_UNKNOWN,
                frame=d.MAV_FRAME_BODY_FRD,
                obstacle_id=obj.track_id & 0xFFFF,
                x=x,
                y=y,
                z=z,
                min_distance=min_distance_m,
                max_distance=max_distance_m,
            )
        )
    return out


EARTH_RADIUS_M = 6_378_137.0


def adsb_vehicles(
    objects: Sequence[ObjectResult],
    vehicle_pos_ned_m: np.ndarray,
    origin_lat_deg: float,
    origin_lon_deg: float,
    origin_alt_m: float,
    object_radius_m: float,
    velocities_ned_mps: dict[int, np.ndarray],
) -> list[d.MAVLink_adsb_vehicle_message]:
    """Moving objects of known range as ADS-B traffic (ICAO address 0x7C0000 + track id).

    Position: the vehicle's local position plus range × NED bearing, converted to
    latitude/longitude around the local frame's global origin (flat-earth, fine over the
    few hundred metres this concerns). ``velocities_ned_mps`` per track id, if known.
    """
    out = []
    for obj, rng in ranged([o for o in objects if o.state == "moving"], object_radius_m):
        p = np.asarray(vehicle_pos_ned_m, dtype=np.float64) + rng * obj.bearing_ned
        lat = origin_lat_deg + math.degrees(p[0] / EARTH_RADIUS_M)
        lon = origin_lon_deg + math.degrees(
            p[1] / (EARTH_RADIUS_M * math.cos(math.radians(origin_lat_deg)))
        )
        alt = origin_alt_m - p[2]
        v = velocities_ned_mps.get(obj.track_id, np.zeros(3))
        heading = math.degrees(math.atan2(v[1], v[0])) % 360.0
        flags = (
            d.ADSB_FLAGS_VALID_COORDS
            | d.ADSB_FLAGS_VALID_ALTITUDE
            | (
                d.ADSB_FLAGS_VALID_HEADING | d.ADSB_FLAGS_VALID_VELOCITY
                if obj.track_id in velocities_ned_mps
                else 0
            )
        )
        out.append(
            d.MAVLink_adsb_vehicle_message(
                ICAO_address=0x7C0000 + (obj.track_id & 0xFFFF),
                lat=round(lat * 1e7),
                lon=round(lon * 1e7),
                altitude_type=d.ADSB_ALTITUDE_TYPE_GEOMETRIC,
                altitude=round(alt * 1000),
                heading=round(heading * 100) % 36000,
                hor_velocity=round(math.hypot(v[0], v[1]) * 100),
                ver_velocity=round(-v[2] * 100),
                callsign=f"TCM{obj.track_id % 10000:04d}".encode(),
                emitter_type=d.ADSB_EMITTER_TYPE_UNASSIGNED,
                tslc=0,
                flags=flags,
                squawk=0,
            )
        )
    return out
