"""The HighD file format: column names and types of ``NN_tracks.csv``, ``NN_tracksMeta.csv`` and
``NN_recordingMeta.csv`` as the official format defines them. Image axes: x right, **y down**, metres; ``x, y``
is the box's top-left corner, ``width`` the vehicle length (along x), ``height`` its width.
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
