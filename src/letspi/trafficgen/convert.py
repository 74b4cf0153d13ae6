"""SUMO FCD -> HighD ``states``/``vehicles`` frames (image axes, top-left box corner).

Conventions:
- SUMO FCD ``x, y`` is the **front-bumper centre**, SUMO y points **up**.
- HighD image axes: x right, y **down**; ``x, y`` is the top-left corner of the axis-aligned box,
  ``width`` = vehicle length, ``height`` = vehicle width. Image x = SUMO x - window start,
  image y = ``image_y_ref_m`` - SUMO y (see :mod:`letspi.trafficgen.network`).
- Box centre = front centre minus half the length along the heading; the heading is taken from
  the (smoothed) front trajectory so that it is as smooth as the trajectory itself.
- Velocities/accelerations are time derivatives (central differences, one-sided at track ends)
  of the written box centre: they are consistent with the positions by construction.

SUMO's continuous (non-sublane) lane change moves the vehicle sideways at constant lateral
speed, i.e. with lateral-acceleration spikes of about 25 m/s² at its start and end when
differentiated at 25 Hz. Each lane-change ramp is therefore re-timed with a quintic
"smootherstep" profile over the same start/end instants and lane centres (peak lateral
acceleration 5.77·w/T², about 1.35 m/s² for w = 3.75 m, T = 4 s; zero lateral speed and
acceleration at both ends). Start, end and target lane are SUMO's, only the shape changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from letspi.highd.schema import DRIVING_DIRECTION_LOWER, DRIVING_DIRECTION_UPPER
from letspi.trafficgen.demand import VehicleSpec
from letspi.trafficgen.network import HighwayNetwork
from letspi.trafficgen.simulate import STEP_S

STATE_COLUMNS = ("frame", "id", "x", "y", "width", "height",
                 "xVelocity", "yVelocity", "xAcceleration", "yAcceleration")
_REST_TOL_M = 1e-3  # a vehicle within 1 mm of a lane centre is not changing lanes


@dataclass(frozen=True)
class ImageTracks:
    """All vehicles over the whole simulation in HighD image axes (before window clipping).

    Attributes:
        data: columns ``step`` (simulation step index, time / 0.04 s), ``sumo_id``, ``x``, ``y``
            (top-left corner, image axes) [m], ``width`` (length), ``height`` (width) [m],
            ``xVelocity``, ``yVelocity`` [m/s], ``xAcceleration``, ``yAcceleration`` [m/s²],
            ``drivingDirection``, ``class``; sorted by (sumo_id, step).
    """

    data: pd.DataFrame


def _smootherstep(f: np.ndarray) -> np.ndarray:
    f = np.clip(f, 0.0, 1.0)
    return f * f * f * (f * (6.0 * f - 15.0) + 10.0)


def smooth_lane_changes(t: np.ndarray, y: np.ndarray, vehicle: np.ndarray,
                        centres: np.ndarray) -> np.ndarray:
    """Replace SUMO's linear lateral ramps by quintic ones between the same anchor samples.

    Args:
        t: time [s], shape (N,), sorted within each vehicle.
        y: lateral coordinate [m] (SUMO y of the front), shape (N,).
        vehicle: integer vehicle code per row, shape (N,); rows of one vehicle are contiguous.
        centres: lane-centre y [m] per row (nearest-centre search uses all centres of the row's
            carriageway), shape (N, n_lanes).

    Returns:
        The smoothed lateral coordinate, shape (N,). Ramps touching the start or end of a
        vehicle's data (no anchor at rest) are left unchanged.
    """
    out = y.copy()
    moving = np.min(np.abs(y[:, None] - centres), axis=1) > _REST_TOL_M
    if not moving.any():
        return out
    idx = np.flatnonzero(moving)
    # Contiguous runs of "moving" rows within one vehicle.
    breaks = np.flatnonzero((np.diff(idx) != 1) | (np.diff(vehicle[idx]) != 0)) + 1
    n = len(y)
    for run in np.split(idx, breaks):
        a, b = run[0] - 1, run[-1] + 1
        if a < 0 or b >= n or vehicle[a] != vehicle[run[0]] or vehicle[b] != vehicle[run[0]]:
            continue
        frac = (t[run] - t[a]) / (t[b] - t[a])
        out[run] = y[a] + (y[b] - y[a]) * _smootherstep(frac)
    return out


def _gradient(values: np.ndarray, t: np.ndarray, first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """d(values)/dt per vehicle: central differences inside, one-sided at each track's ends.

    ``first``/``last`` flag the first/last row of each vehicle; single-row tracks get 0.
    """
    n = len(values)
    prev = np.arange(n) - 1
    nxt = np.arange(n) + 1
    prev[first] = np.flatnonzero(first)  # one-sided: use the row itself
    nxt[last] = np.flatnonzero(last)
    prev = np.clip(prev, 0, n - 1)
    nxt = np.clip(nxt, 0, n - 1)
    dt = t[nxt] - t[prev]
    with np.errstate(invalid="ignore", divide="ignore"):
        grad = (values[nxt] - values[prev]) / dt
    return np.where(dt > 0, grad, 0.0)


def _box_centres(fx: np.ndarray, fy: np.ndarray, t: np.ndarray, first: np.ndarray, last: np.ndarray,
                 east: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Box centres [m] (SUMO axes) half a length behind the front points, along the heading of the
    smoothed front trajectory (the road direction when slower than 0.5 m/s)."""
    vfx, vfy = _gradient(fx, t, first, last), _gradient(fy, t, first, last)
    speed = np.hypot(vfx, vfy)
    road_dir = np.where(east, 1.0, -1.0)
    slow = speed < 0.5
    ux = np.where(slow, road_dir, vfx / np.where(slow, 1.0, speed))
    uy = np.where(slow, 0.0, vfy / np.where(slow, 1.0, speed))
    return fx - 0.5 * length * ux, fy - 0.5 * length * uy


def fcd_to_image(fcd: pd.DataFrame, specs: list[VehicleSpec], network: HighwayNetwork) -> ImageTracks:
    """Convert SUMO FCD (front centre, y up) to HighD image-axis boxes with derivatives.

    Args:
        fcd: output of :func:`letspi.trafficgen.simulate.read_fcd` (sorted by id, time).
        specs: the inserted vehicles (dimensions, class, direction).
        network: geometry and image transform.
    """
    spec_table = pd.DataFrame({
        "sumo_id": [s.vid for s in specs],
        "length": [s.length_m for s in specs],
        "vwidth": [s.width_m for s in specs],
        "east": [s.east for s in specs],
        "class": ["Truck" if s.kind == "truck" else "Car" for s in specs],  # vans -> "Car"
    })
    df = fcd.rename(columns={"id": "sumo_id"}).merge(spec_table, on="sumo_id", how="left",
                                                     validate="many_to_one")
    if df["length"].isna().any():
        raise RuntimeError("FCD contains vehicles that are not in the demand")
    df = df.sort_values(["sumo_id", "time"], kind="stable").reset_index(drop=True)

    t = df["time"].to_numpy(np.float64)
    vehicle = pd.factorize(df["sumo_id"])[0]
    first = np.r_[True, vehicle[1:] != vehicle[:-1]]
    last = np.r_[vehicle[1:] != vehicle[:-1], True]
    east = df["east"].to_numpy(bool)
    length = df["length"].to_numpy(np.float64)
    # Lanes a vehicle can rest on (main and auxiliary), so that merges from an acceleration
    # lane are smoothed like any lane change.
    centres = np.where(east[:, None], network.smoothing_centres(True)[None, :],
                       network.smoothing_centres(False)[None, :])

    fx = df["x"].to_numpy(np.float64)
    fy = smooth_lane_changes(t, df["y"].to_numpy(np.float64), vehicle, centres)
    cx, cy = _box_centres(fx, fy, t, first, last, east, length)

    img_cx = cx - network.window_x0_m
    img_cy = network.image_y_ref_m - cy  # image y points down
    vx = _gradient(img_cx, t, first, last)
    vy = _gradient(img_cy, t, first, last)
    ax = _gradient(vx, t, first, last)
    ay = _gradient(vy, t, first, last)

    width = df["vwidth"].to_numpy(np.float64)
    data = pd.DataFrame({
        "step": np.rint(t / STEP_S).astype(np.int64),
        "sumo_id": df["sumo_id"].to_numpy(),
        "x": img_cx - 0.5 * length,
        "y": img_cy - 0.5 * width,
        "width": length,
        "height": width,
        "xVelocity": vx,
        "yVelocity": vy,
        "xAcceleration": ax,
        "yAcceleration": ay,
        "drivingDirection": np.where(east, DRIVING_DIRECTION_LOWER, DRIVING_DIRECTION_UPPER),
        "class": df["class"].to_numpy(),
    })
    return ImageTracks(data=data)


def clip_to_window(tracks: ImageTracks, *, first_step: int, n_steps: int, window_m: float,
                   upper_y_m: tuple[float, float] | None = None,
                   lower_y_m: tuple[float, float] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Cut one recording out of the image tracks.

    A vehicle is recorded in the frames where its whole box lies in ``[0, window_m]`` along x,
    its box centre lies on its main carriageway (image y within ``upper_y_m`` for direction 1,
    ``lower_y_m`` for direction 2, when given: ramps and auxiliary lanes are not recorded) and
    the step is in ``[first_step, first_step + n_steps)``; only its first contiguous run of
    such frames is kept, and runs of a single frame are dropped. Frames start at 1; vehicle ids
    start at 1, ordered by first frame, then driving direction, then x.

    Returns:
        ``(states, vehicles)``: ``states`` with :data:`STATE_COLUMNS` sorted by (id, frame),
        ``vehicles`` with ``id, class, drivingDirection`` (plus ``sumo_id`` for tracing).
    """
    d = tracks.data
    inside = ((d["step"] >= first_step) & (d["step"] < first_step + n_steps)
              & (d["x"] >= 0.0) & (d["x"] + d["width"] <= window_m))
    if upper_y_m is not None and lower_y_m is not None:
        cy = d["y"] + 0.5 * d["height"]
        upper = d["drivingDirection"] == DRIVING_DIRECTION_UPPER
        band_lo = np.where(upper, upper_y_m[0], lower_y_m[0])
        band_hi = np.where(upper, upper_y_m[1], lower_y_m[1])
        inside &= (cy >= band_lo) & (cy <= band_hi)
    d = d.loc[inside.to_numpy()]
    if d.empty:
        return (pd.DataFrame(columns=list(STATE_COLUMNS)),
                pd.DataFrame(columns=["id", "class", "drivingDirection", "sumo_id"]))
    sid = d["sumo_id"].to_numpy()
    step = d["step"].to_numpy()
    new_run = np.r_[True, (sid[1:] != sid[:-1]) | (np.diff(step) != 1)]
    run_no = np.cumsum(new_run)
    first_run = pd.Series(run_no, index=d.index).groupby(sid).transform("min")
    d = d.loc[run_no == first_run.to_numpy()]
    sizes = d.groupby("sumo_id")["step"].transform("size")
    d = d.loc[sizes.to_numpy() >= 2].copy()
    d["frame"] = d["step"] - first_step + 1

    firsts = d.groupby("sumo_id", sort=False).first().reset_index()
    firsts = firsts.sort_values(["frame", "drivingDirection", "x", "sumo_id"], kind="stable")
    firsts["id"] = np.arange(1, len(firsts) + 1)
    id_map = dict(zip(firsts["sumo_id"], firsts["id"], strict=True))
    d["id"] = d["sumo_id"].map(id_map).astype(np.int64)
    states = d.sort_values(["id", "frame"], kind="stable")[list(STATE_COLUMNS)].reset_index(drop=True)
    states["frame"] = states["frame"].astype(np.int64)
    vehicles = firsts[["id", "class", "drivingDirection", "sumo_id"]].reset_index(drop=True)
    vehicles["drivingDirection"] = vehicles["drivingDirection"].astype(np.int64)
    return states, vehicles
