"""SUMO FCD (front-bumper centre, y up) -> HighD ``states``/``vehicles`` frames (image axes, top-left box corner).

The box centre lies half a length behind the front along the smoothed heading; velocities and accelerations are
central differences of the written centres. SUMO's linear lateral lane-change ramps become quintic smootherstep
ones between the same instants (zero lateral speed and acceleration at both ends)."""

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
    """All vehicles over the whole simulation in HighD image axes, before window clipping. ``data``: ``step`` (time /
    0.04 s), ``sumo_id``, the HighD box [m] and motion columns [m/s, m/s²], ``drivingDirection``, ``class``; sorted by
    (sumo_id, step)."""

    data: pd.DataFrame


def _smootherstep(f: np.ndarray) -> np.ndarray:
    f = np.clip(f, 0.0, 1.0)
    return f * f * f * (f * (6.0 * f - 15.0) + 10.0)


def smooth_lane_changes(t: np.ndarray, y: np.ndarray, vehicle: np.ndarray,
                        centres: np.ndarray) -> np.ndarray:
    """Replace SUMO's linear lateral ramps by quintic ones between the same anchor samples. ``t`` (N,) [s] sorted within
    each vehicle; ``y`` (N,) SUMO y of the front [m]; ``vehicle`` (N,) int code, rows of one vehicle contiguous;
    ``centres`` (N, n_lanes) lane-centre y [m] of the row's carriageway. Returns the smoothed (N,) y; ramps touching a
    vehicle's first or last row (no anchor at rest) stay unchanged."""
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
    """d(values)/dt per vehicle: central differences, one-sided at each track's ends (``first``/``last`` flags); 0 for
    single rows."""
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
    """SUMO FCD (``read_fcd``) as HighD image-axis boxes with derivatives; ``specs``: each vehicle's dimensions,
    class (vans become "Car") and direction."""
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
    # main and auxiliary lanes: merges from an acceleration lane are smoothed like any lane change
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
    """Cut one recording out of the image tracks. A vehicle is recorded in the steps ``[first_step, first_step +
    n_steps)`` where its whole box is in ``[0, window_m]`` along x and (when the bands are given) its centre on its main
    carriageway; only its first contiguous run is kept, single frames are dropped. Frames and ids start at 1, ids
    ordered by first frame, direction, x. Returns ``states`` (``STATE_COLUMNS``, sorted by (id, frame)) and ``vehicles``
    (``id, class, drivingDirection, sumo_id``)."""
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
