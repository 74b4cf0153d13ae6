"""Straight SUMO networks for closed-loop runs: one road per scenario ("slot"), cached per lane layout. Slot k's
coordinates are a translation of the ego frame: ``X = x + x_origin_m``, ``Y = y + left_edge_y_m[k] - (left road edge
y)``; SUMO lane 0 is the rightmost; widths rounded to 1 cm are the layout key."""

from __future__ import annotations

import hashlib
import os
import subprocess
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from letspi.simulation.config import OFF_ROAD_MARGIN_M, ClosedLoopConfig
from letspi.trafficgen.binaries import sumo_binary

LayoutKey = tuple[float, ...]
VTYPE_ID = "cl"
WIDTH_RESOLUTION_M = 0.01
MIN_LANE_WIDTH_M, MAX_LANE_WIDTH_M = 2.0, 6.0


def layout_key(marking_y_m: np.ndarray) -> LayoutKey:
    """Lane widths [m] (right to left, rounded to 1 cm) of one scenario's markings (M,), NaN padded."""
    m = np.asarray(marking_y_m, dtype=np.float64)
    m = m[np.isfinite(m)]
    if m.size < 2:
        raise ValueError(f"a road needs at least two markings, got {m.size}")
    widths = np.round(np.diff(m) / WIDTH_RESOLUTION_M) * WIDTH_RESOLUTION_M
    if np.any(widths < MIN_LANE_WIDTH_M) or np.any(widths > MAX_LANE_WIDTH_M):
        raise ValueError(f"lane widths {widths.tolist()} m outside [{MIN_LANE_WIDTH_M}, {MAX_LANE_WIDTH_M}] m")
    return tuple(float(w) for w in widths)


def layout_keys(marking_y_m: np.ndarray) -> list[LayoutKey]:
    """``layout_key`` of every scenario of a (B, M) marking array."""
    return [layout_key(row) for row in np.asarray(marking_y_m)]


@dataclass(frozen=True)
class SlotNetwork:
    """A built network (files on disk) and its transform: ``net_file``, ``route_file`` (vehicle type, a route per
    slot), ``widths_m`` right to left [m], ``n_slots``, ``x_origin_m`` (SUMO x of ego x = 0) [m] and
    ``left_edge_y_m`` (n_slots,) SUMO y of each road's left edge [m]."""

    net_file: Path
    route_file: Path
    widths_m: LayoutKey
    n_slots: int
    x_origin_m: float
    left_edge_y_m: np.ndarray

    def route_id(self, slot: int) -> str:
        return f"r{slot}"

    def y_offset_m(self, slots: np.ndarray, marking_y_m: np.ndarray) -> np.ndarray:
        """SUMO y minus ego-frame y for scenarios on ``slots`` (K,) with markings (K, M) -> (K,)."""
        top = np.nanmax(np.asarray(marking_y_m, dtype=np.float64), axis=1)
        return self.left_edge_y_m[np.asarray(slots)] - top


def _vtype_xml(config: ClosedLoopConfig) -> str:
    d = config.driver
    return (
        f'<vType id="{VTYPE_ID}" vClass="passenger" length="4.5" width="1.8" minGap="{d.min_gap_m}" '
        f'accel="{d.accel_mps2}" decel="{d.decel_mps2}" emergencyDecel="{d.emergency_decel_mps2}" '
        f'apparentDecel="{d.decel_mps2}" tau="{d.default_headway_s}" sigma="0" speedFactor="1" speedDev="0" '
        f'maxSpeed="{d.desired_speed_bounds_mps[1]}" carFollowModel="IDM" laneChangeModel="SL2015"/>'
    )


def _write_inputs(
    directory: Path, stem: str, widths: LayoutKey, n_slots: int, config: ClosedLoopConfig
) -> tuple[Path, Path, Path]:
    length = config.road_behind_m + config.road_ahead_m
    nodes, edges, routes = (directory / f"{stem}.nod.xml", directory / f"{stem}.edg.xml", directory / f"{stem}.rou.xml")
    node_rows, edge_rows, route_rows = [], [], []
    lanes = "".join(f'<lane index="{i}" width="{w:.2f}"/>' for i, w in enumerate(widths))
    for k in range(n_slots):
        y = k * config.slot_spacing_m
        node_rows.append(f'<node id="a{k}" x="0" y="{y:.3f}"/><node id="b{k}" x="{length:.3f}" y="{y:.3f}"/>')
        edge_rows.append(f'<edge id="s{k}" from="a{k}" to="b{k}" numLanes="{len(widths)}" speed="60">{lanes}</edge>')
        route_rows.append(f'<route id="r{k}" edges="s{k}"/>')
    nodes.write_text("<nodes>\n" + "\n".join(node_rows) + "\n</nodes>\n")
    edges.write_text("<edges>\n" + "\n".join(edge_rows) + "\n</edges>\n")
    routes.write_text("<routes>\n" + _vtype_xml(config) + "\n" + "\n".join(route_rows) + "\n</routes>\n")
    return nodes, edges, routes


def _check_lanes(net_file: Path, widths: LayoutKey, n_slots: int, spacing_m: float) -> None:
    """The built lanes must sit where the transform assumes (left edge at the slot's y)."""
    expected_left = np.arange(n_slots) * spacing_m
    for edge in ET.parse(net_file).getroot().iter("edge"):
        eid = edge.get("id", "")
        if edge.get("function") == "internal" or not eid.startswith("s"):
            continue
        k = int(eid[1:])
        top = max(int(lane.get("index", "0")) for lane in edge.iter("lane"))
        for lane in edge.iter("lane"):
            if int(lane.get("index", "0")) != top:
                continue
            y = float(lane.get("shape", "0,0").split()[0].split(",")[1])
            left = y + float(lane.get("width", "0")) / 2.0
            if abs(left - expected_left[k]) > 1e-3:
                raise RuntimeError(f"netconvert placed road {eid} at y = {left:.4f}, expected {expected_left[k]:.4f}")


def build_slot_network(directory: Path, widths: LayoutKey, n_slots: int, config: ClosedLoopConfig) -> SlotNetwork:
    """Write and netconvert a network of ``n_slots`` parallel roads with lanes ``widths``."""
    road_width = sum(widths)
    if config.slot_spacing_m < road_width + 2 * OFF_ROAD_MARGIN_M + 10.0:
        raise ValueError(f"slot_spacing_m {config.slot_spacing_m} m is too small for a {road_width:.1f} m road")
    tag = f"{widths}|{n_slots}|{config.road_behind_m}|{config.road_ahead_m}|{config.slot_spacing_m}|{config.driver}"
    stem = "net-" + hashlib.sha256(tag.encode()).hexdigest()[:16]
    net_file = directory / f"{stem}.net.xml"
    nodes, edges, routes = _write_inputs(directory, stem, widths, n_slots, config)
    tmp = directory / f"{stem}.{os.getpid()}.tmp.net.xml"
    cmd = [
        sumo_binary("netconvert"), "--node-files", str(nodes), "--edge-files", str(edges), "--output-file", str(tmp),
        "--offset.disable-normalization", "true", "--no-turnarounds", "true", "--no-warnings", "true",
        "--precision", "6",
    ]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"netconvert failed ({proc.returncode}): {proc.stderr.strip()}")
    os.replace(tmp, net_file)
    _check_lanes(net_file, widths, n_slots, config.slot_spacing_m)
    return SlotNetwork(net_file=net_file, route_file=routes, widths_m=widths, n_slots=n_slots,
                       x_origin_m=config.road_behind_m,
                       left_edge_y_m=np.arange(n_slots, dtype=np.float64) * config.slot_spacing_m)


class NetworkCache:
    """Networks built so far in ``directory``, by (lane layout, slots). Owned by one process."""

    def __init__(self, directory: Path, config: ClosedLoopConfig) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.config = config
        self._built: dict[tuple[LayoutKey, int], SlotNetwork] = {}
        self.builds = 0
        self.build_s = 0.0

    def get(self, widths: LayoutKey, n_slots: int) -> SlotNetwork:
        key = (widths, n_slots)
        if key not in self._built:
            t0 = time.perf_counter()
            self._built[key] = build_slot_network(self.directory, widths, n_slots, self.config)
            self.build_s += time.perf_counter() - t0
            self.builds += 1
        return self._built[key]
