"""The HighD file format: column names and types, exactly as the official format defines them.

Files per recording ``NN`` (two-digit, zero-padded): ``NN_tracks.csv`` (one row per vehicle per
frame), ``NN_tracksMeta.csv`` (one row per vehicle), ``NN_recordingMeta.csv`` (one row).

Image axes: x to the right, **y down**, metres. ``x, y`` in tracks are the *top-left corner* of
the bounding box; ``width`` is the vehicle length (along x) and ``height`` its width.
"""

from typing import Final

TRACKS_COLUMNS: Final[tuple[str, ...]] = (
    "frame", "id", "x", "y", "width", "height",
    "xVelocity", "yVelocity", "xAcceleration", "yAcceleration",
    "frontSightDistance", "backSightDistance", "dhw", "thw", "ttc", "precedingXVelocity",
    "precedingId", "followingId",
    "leftPrecedingId", "leftAlongsideId", "leftFollowingId",
    "rightPrecedingId", "rightAlongsideId", "rightFollowingId",
    "laneId",
)
TRACKS_INT_COLUMNS: Final[frozenset[str]] = frozenset({
    "frame", "id", "precedingId", "followingId",
    "leftPrecedingId", "leftAlongsideId", "leftFollowingId",
    "rightPrecedingId", "rightAlongsideId", "rightFollowingId", "laneId",
})

TRACKS_META_COLUMNS: Final[tuple[str, ...]] = (
    "id", "width", "height", "initialFrame", "finalFrame", "numFrames", "class",
    "drivingDirection", "traveledDistance", "minXVelocity", "maxXVelocity", "meanXVelocity",
    "minDHW", "minTHW", "minTTC", "numLaneChanges",
)
TRACKS_META_INT_COLUMNS: Final[frozenset[str]] = frozenset({
    "id", "initialFrame", "finalFrame", "numFrames", "drivingDirection", "numLaneChanges",
})
TRACKS_META_STR_COLUMNS: Final[frozenset[str]] = frozenset({"class"})
VEHICLE_CLASSES: Final[tuple[str, ...]] = ("Car", "Truck")

RECORDING_META_COLUMNS: Final[tuple[str, ...]] = (
    "id", "frameRate", "locationId", "speedLimit", "month", "weekDay", "startTime", "duration",
    "totalDrivenDistance", "totalDrivenTime", "numVehicles", "numCars", "numTrucks",
    "upperLaneMarkings", "lowerLaneMarkings",
)
RECORDING_META_INT_COLUMNS: Final[frozenset[str]] = frozenset({
    "id", "frameRate", "locationId", "numVehicles", "numCars", "numTrucks",
})
RECORDING_META_STR_COLUMNS: Final[frozenset[str]] = frozenset({
    "month", "weekDay", "startTime", "upperLaneMarkings", "lowerLaneMarkings",
})

DRIVING_DIRECTION_UPPER: Final = 1  # travels towards -x on the upper carriageway
DRIVING_DIRECTION_LOWER: Final = 2  # travels towards +x on the lower carriageway


def tracks_file(recording_id: int) -> str:
    return f"{recording_id:02d}_tracks.csv"


def tracks_meta_file(recording_id: int) -> str:
    return f"{recording_id:02d}_tracksMeta.csv"


def recording_meta_file(recording_id: int) -> str:
    return f"{recording_id:02d}_recordingMeta.csv"


def highway_image_file(recording_id: int) -> str:
    """The recording's background image (real HighD: the aerial view; generated: the drawn road)."""
    return f"{recording_id:02d}_highway.png"


#: metres per pixel of ``NN_highway.png``: HighD's images are 0.1 m per pixel scaled down by 4
#: (the factor readers such as ``lxd-io`` divide image coordinates by)
HIGHWAY_IMAGE_M_PER_PX: Final = 0.4
