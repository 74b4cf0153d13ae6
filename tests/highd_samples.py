"""Hand-made HighD recordings for tests (positions chosen so derived values are easy to compute).

Road: 3+3 lanes. Upper markings y = 10.0, 13.5, 17.0, 20.5 (lanes 2, 3, 4), lower markings
y = 24.0, 27.5, 31.0, 34.5 (lanes 6, 7, 8). 50 frames at 25 Hz (dt = 0.04 s), constant velocities.

Direction 2 (towards +x, lower lanes; left = smaller y):
    1  Car   lane 7, x0 = 50,  vx = 30, frames 1-50
    2  Car   lane 7, x0 = 80,  vx = 25, frames 1-50
    3  Truck lane 8, x0 = 60,  vx = 22, frames 1-50 (15 m x 2.5 m)
    4  Car   lane 6, x0 = 48,  vx = 33, frames 1-50 (alongside car 1 at frame 1)
    5  Car   lane 8 -> 7 (centre y linear from frame 15 to 34, lane 7 from frame 25 on),
             x0 = 10 at frame 5, vx = 28, frames 5-50
Direction 1 (towards -x, upper lanes; left = larger y):
    10 Car   lane 3, x0 = 300, vx = -30
    11 Car   lane 3, x0 = 330, vx = -32 (follows car 10)
    12 Car   lane 4, x0 = 310, vx = -30
Cars are 4.5 m x 1.8 m.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from letspi.highd.derive import build_recording
from letspi.highd.types import Recording

UPPER_MARKINGS = (10.0, 13.5, 17.0, 20.5)
LOWER_MARKINGS = (24.0, 27.5, 31.0, 34.5)
FRAME_RATE = 25
DT = 1.0 / FRAME_RATE
CAR = (4.5, 1.8)
TRUCK = (15.0, 2.5)
LANE_CENTRE_Y = {3: 15.25, 4: 18.75, 6: 25.75, 7: 29.25, 8: 32.75}


def _vehicle(
    vid: int, size: tuple[float, float], x0: float, vx: float, centre_y: np.ndarray | float, frames: np.ndarray
) -> pd.DataFrame:
    length, width = size
    t = (frames - frames[0]) * DT
    cy = np.broadcast_to(np.asarray(centre_y, dtype=np.float64), frames.shape)
    vy = np.gradient(cy, DT) if len(frames) > 1 else np.zeros(len(frames))
    return pd.DataFrame(
        {
            "frame": frames,
            "id": vid,
            "x": x0 + vx * t,
            "y": cy - width / 2.0,
            "width": length,
            "height": width,
            "xVelocity": vx,
            "yVelocity": vy,
            "xAcceleration": 0.0,
            "yAcceleration": 0.0,
        }
    )


def sample_states() -> tuple[pd.DataFrame, pd.DataFrame]:
    """The (states, vehicles) inputs of :func:`build_recording` for the recording described above."""
    full = np.arange(1, 51)
    late = np.arange(5, 51)
    lc_y = np.interp(late, [15, 34], [LANE_CENTRE_Y[8], LANE_CENTRE_Y[7]])
    parts = [
        _vehicle(1, CAR, 50.0, 30.0, LANE_CENTRE_Y[7], full),
        _vehicle(2, CAR, 80.0, 25.0, LANE_CENTRE_Y[7], full),
        _vehicle(3, TRUCK, 60.0, 22.0, LANE_CENTRE_Y[8], full),
        _vehicle(4, CAR, 48.0, 33.0, LANE_CENTRE_Y[6], full),
        _vehicle(5, CAR, 10.0, 28.0, lc_y, late),
        _vehicle(10, CAR, 300.0, -30.0, LANE_CENTRE_Y[3], full),
        _vehicle(11, CAR, 330.0, -32.0, LANE_CENTRE_Y[3], full),
        _vehicle(12, CAR, 310.0, -30.0, LANE_CENTRE_Y[4], full),
    ]
    # shuffle row order: build_recording must not rely on the input order
    states = pd.concat(parts, ignore_index=True).sample(frac=1.0, random_state=0).reset_index(drop=True)
    vehicles = pd.DataFrame(
        {
            "id": [1, 2, 3, 4, 5, 10, 11, 12],
            "class": ["Car", "Car", "Truck", "Car", "Car", "Car", "Car", "Car"],
            "drivingDirection": [2, 2, 2, 2, 2, 1, 1, 1],
        }
    )
    return states, vehicles


def sample_recording(recording_id: int = 1) -> Recording:
    states, vehicles = sample_states()
    return build_recording(
        states,
        vehicles,
        recording_id=recording_id,
        upper_markings_y_m=UPPER_MARKINGS,
        lower_markings_y_m=LOWER_MARKINGS,
        frame_rate_hz=FRAME_RATE,
        location_id=2,
        speed_limit_mps=33.33,
        month="09",
        week_day="Tue",
        start_time="10:15",
    )


def synthetic_states(n_vehicles: int, n_frames_per_vehicle: int, seed: int = 0) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Large random constant-speed traffic on the same road (for timing; vehicles enter staggered)."""
    rng = np.random.default_rng(seed)
    ids = np.arange(1, n_vehicles + 1)
    direction = rng.integers(1, 3, n_vehicles)
    lanes = np.where(direction == 2, rng.choice([6, 7, 8], n_vehicles), rng.choice([2, 3, 4], n_vehicles))
    lane_y = {2: 11.75, 3: 15.25, 4: 18.75, 6: 25.75, 7: 29.25, 8: 32.75}
    cy = np.array([lane_y[int(v)] for v in lanes])
    truck = rng.random(n_vehicles) < 0.15
    length = np.where(truck, 15.0, 4.5)
    width = np.where(truck, 2.5, 1.8)
    speed = rng.uniform(20.0, 40.0, n_vehicles)
    first = (np.arange(n_vehicles) * 3).astype(np.int64) + 1
    k = np.tile(np.arange(n_frames_per_vehicle), n_vehicles)
    v_idx = np.repeat(np.arange(n_vehicles), n_frames_per_vehicle)
    vx = np.where(direction == 2, speed, -speed)[v_idx]
    x0 = np.where(direction == 2, 0.0, 1000.0)[v_idx]
    states = pd.DataFrame(
        {
            "frame": first[v_idx] + k,
            "id": ids[v_idx],
            "x": x0 + vx * k * DT,
            "y": cy[v_idx] - width[v_idx] / 2.0 + rng.normal(0.0, 0.2, len(k)),
            "width": length[v_idx],
            "height": width[v_idx],
            "xVelocity": vx,
            "yVelocity": 0.0,
            "xAcceleration": 0.0,
            "yAcceleration": 0.0,
        }
    )
    vehicles = pd.DataFrame({"id": ids, "class": np.where(truck, "Truck", "Car"), "drivingDirection": direction})
    return states, vehicles
