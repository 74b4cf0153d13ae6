"""Two-direction highway built with SUMO's ``netconvert`` from plain XML, in the three layouts of ``LayoutConfig``.

SUMO coordinates, y **up**: eastbound lanes (edges "E…", HighD direction 2) below y = 0, westbound ("W…",
direction 1) above the median. Only the main carriageway is recorded; lane positions are read back from the
``.net.xml`` (netconvert may shift coordinates)."""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from letspi.trafficgen.binaries import sumo_binary
from letspi.trafficgen.config import LayoutConfig

ACCEL_LANE_M = 250.0  # total length of the acceleration lane (on_ramp)
_RAMP_M = 250.0  # ramp length before the acceleration lane
_RAMP_OFFSET_M = 30.0  # lateral distance of the ramp start from the road edge
_RAMP_SPEED_MPS = 27.8  # 100 km/h on the ramp


@dataclass(frozen=True)
class HighwayGeometry:
    """Design parameters of the generated highway [m, m/s]. ``lanes_per_direction`` (2 or 3); ``median_m``: between the
    inner road edges; ``approach_m``: driven before the window per direction; ``window_m``: HighD's is about 420 m;
    ``lane_speed_mps``: high, so vehicles keep their own desired speed; ``image_top_m``: image y of the upper road
    edge."""

    lanes_per_direction: int = 3
    lane_width_m: float = 3.75
    median_m: float = 4.0
    approach_m: float = 700.0
    window_m: float = 420.0
    lane_speed_mps: float = 60.0
    image_top_m: float = 8.0

    @property
    def road_length_m(self) -> float:
        return 2.0 * self.approach_m + self.window_m


@dataclass(frozen=True)
class Entry:
    """Where traffic is inserted: ``route`` id, ``east`` (HighD direction 2), ``n_lanes`` (index 0 = rightmost),
    ``flow_share`` of the direction's flow, ``ramp``."""

    route: str
    east: bool
    n_lanes: int
    flow_share: float
    ramp: bool = False


@dataclass(frozen=True)
class HighwayNetwork:
    """The generated network as read back from the ``.net.xml`` (in a temporary directory). Image x = SUMO x -
    ``window_x0_m``; image y = ``image_y_ref_m`` - SUMO y. ``*_centres_y_m``: SUMO y of the main lane centres (index 0 =
    rightmost); ``*_aux_y_m``: of the auxiliary lane (NaN for ``straight``); ``upper/lower_markings_y_m``: image y of
    the main carriageways' markings, ascending, road edges included; ``routes``: route id -> edges; ``entries``: where
    traffic is inserted."""

    net_file: Path
    geometry: HighwayGeometry
    layout: LayoutConfig
    window_x0_m: float
    image_y_ref_m: float
    east_centres_y_m: np.ndarray
    west_centres_y_m: np.ndarray
    upper_markings_y_m: np.ndarray
    lower_markings_y_m: np.ndarray
    east_aux_y_m: float = float("nan")
    west_aux_y_m: float = float("nan")
    routes: dict[str, list[str]] = field(default_factory=dict)
    entries: list[Entry] = field(default_factory=list)

    def smoothing_centres(self, east: bool) -> np.ndarray:
        """Lane centres (main + auxiliary) a vehicle can rest on, SUMO y [m]."""
        main = self.east_centres_y_m if east else self.west_centres_y_m
        aux = self.east_aux_y_m if east else self.west_aux_y_m
        return main if np.isnan(aux) else np.append(main, aux)


@dataclass(frozen=True)
class _Plan:
    nodes: list[tuple[str, float, float]]
    edges: list[tuple[str, str, str, int, float]]  # id, from, to, lanes, speed
    connections: list[tuple[str, str, int, int]]  # from edge, to edge, from lane, to lane
    routes: dict[str, list[str]]
    entries: list[Entry]
    main_edge: dict[bool, tuple[str, int]]  # east -> (edge whose lanes k.. are main, first main index)
    aux_edge: dict[bool, str]  # east -> edge whose lane 0 is the auxiliary lane


def _plan(geometry: HighwayGeometry, layout: LayoutConfig) -> _Plan:
    n = geometry.lanes_per_direction
    length = geometry.road_length_m
    win0 = geometry.approach_m
    speed = geometry.lane_speed_mps
    med = geometry.median_m
    nodes = [("e0", 0.0, 0.0), ("e1", length, 0.0), ("w0", length, med), ("w1", 0.0, med)]
    if layout.kind == "straight":
        return _Plan(nodes, [("E", "e0", "e1", n, speed), ("W", "w0", "w1", n, speed)], [],
                     {"rE": ["E"], "rW": ["W"]},
                     [Entry("rE", True, n, 1.0), Entry("rW", False, n, 1.0)],
                     {True: ("E", 0), False: ("W", 0)}, {})
    # Auxiliary lane end: aux_lane_m past the window entry in each travel direction.
    end_e = win0 + layout.aux_lane_m
    end_w = length - win0 - layout.aux_lane_m
    nodes += [("eb", end_e, 0.0), ("wb", end_w, med)]
    conns: list[tuple[str, str, int, int]] = []
    if layout.kind == "lane_drop":
        edges = [("E", "e0", "eb", n + 1, speed), ("E_out", "eb", "e1", n, speed),
                 ("W", "w0", "wb", n + 1, speed), ("W_out", "wb", "w1", n, speed)]
        for d in ("E", "W"):
            conns += [(d, f"{d}_out", k + 1, k) for k in range(n)]
        return _Plan(nodes, edges, conns, {"rE": ["E", "E_out"], "rW": ["W", "W_out"]},
                     [Entry("rE", True, n + 1, 1.0), Entry("rW", False, n + 1, 1.0)],
                     {True: ("E_out", 0), False: ("W_out", 0)}, {True: "E", False: "W"})
    # on_ramp
    start_e, start_w = end_e - ACCEL_LANE_M, end_w + ACCEL_LANE_M
    outer_e = -(n * geometry.lane_width_m) - _RAMP_OFFSET_M
    outer_w = med + n * geometry.lane_width_m + _RAMP_OFFSET_M
    nodes += [("ea", start_e, 0.0), ("wa", start_w, med),
              ("er", start_e - _RAMP_M, outer_e), ("wr", start_w + _RAMP_M, outer_w)]
    edges = [("E", "e0", "ea", n, speed), ("E_acc", "ea", "eb", n + 1, speed), ("E_out", "eb", "e1", n, speed),
             ("E_ramp", "er", "ea", 1, _RAMP_SPEED_MPS),
             ("W", "w0", "wa", n, speed), ("W_acc", "wa", "wb", n + 1, speed), ("W_out", "wb", "w1", n, speed),
             ("W_ramp", "wr", "wa", 1, _RAMP_SPEED_MPS)]
    for d in ("E", "W"):
        conns += [(d, f"{d}_acc", k, k + 1) for k in range(n)]
        conns += [(f"{d}_ramp", f"{d}_acc", 0, 0)]
        conns += [(f"{d}_acc", f"{d}_out", k + 1, k) for k in range(n)]
    share = layout.ramp_share
    return _Plan(nodes, edges, conns,
                 {"rE": ["E", "E_acc", "E_out"], "rW": ["W", "W_acc", "W_out"],
                  "rE_ramp": ["E_ramp", "E_acc", "E_out"], "rW_ramp": ["W_ramp", "W_acc", "W_out"]},
                 [Entry("rE", True, n, 1.0 - share), Entry("rW", False, n, 1.0 - share),
                  Entry("rE_ramp", True, 1, share, ramp=True), Entry("rW_ramp", False, 1, share, ramp=True)],
                 {True: ("E", 0), False: ("W", 0)}, {True: "E_acc", False: "W_acc"})


def _write_plain_xml(directory: Path, geometry: HighwayGeometry, plan: _Plan) -> list[str]:
    """Write nodes/edges(/connections) and return the netconvert input options."""
    nodes = directory / "highway.nod.xml"
    edges = directory / "highway.edg.xml"
    # Separate node pairs per direction: the median is simply the y distance between them
    # (netconvert spreads each edge's lanes to its right-hand side).
    nodes.write_text("<nodes>\n" + "".join(f'  <node id="{i}" x="{x:.3f}" y="{y:.3f}"/>\n' for i, x, y in plan.nodes)
                     + "</nodes>\n")
    edges.write_text("<edges>\n" + "".join(
        f'  <edge id="{i}" from="{a}" to="{b}" numLanes="{k}" speed="{v:.2f}" width="{geometry.lane_width_m:.3f}"/>\n'
        for i, a, b, k, v in plan.edges) + "</edges>\n")
    opts = ["--node-files", str(nodes), "--edge-files", str(edges)]
    if plan.connections:
        conns = directory / "highway.con.xml"
        conns.write_text("<connections>\n" + "".join(
            f'  <connection from="{a}" to="{b}" fromLane="{i}" toLane="{j}"/>\n' for a, b, i, j in plan.connections)
            + "</connections>\n")
        opts += ["--connection-files", str(conns)]
    return opts


def _lane_table(net_file: Path, edge_ids: set[str]) -> dict[str, list[tuple[int, float, float, float, float]]]:
    """Per edge: (index, y of the centre line [m], width [m], x start, x end) for each lane."""
    out: dict[str, list[tuple[int, float, float, float, float]]] = {}
    for edge in ET.parse(net_file).getroot().iter("edge"):
        if edge.get("function") == "internal" or edge.get("id") not in edge_ids:
            continue
        lanes = []
        for lane in edge.iter("lane"):
            pts = [tuple(float(c) for c in p.split(",")) for p in lane.get("shape", "").split()]
            ys = {round(p[1], 6) for p in pts}
            if len(ys) != 1:
                raise RuntimeError(f"lane {lane.get('id')} is not straight along x: {pts}")
            lanes.append((int(lane.get("index", "0")), pts[0][1], float(lane.get("width", "3.2")),
                          min(pts[0][0], pts[-1][0]), max(pts[0][0], pts[-1][0])))
        out[str(edge.get("id"))] = sorted(lanes)
    return out


def _check_connections(net_file: Path, plan: _Plan) -> None:
    """The lanes must connect exactly as planned (netconvert guesses when told nothing)."""
    if not plan.connections:
        return
    wanted = {(a, b, i, j) for a, b, i, j in plan.connections}
    got = {(c.get("from"), c.get("to"), int(c.get("fromLane", "-1")), int(c.get("toLane", "-1")))
           for c in ET.parse(net_file).getroot().iter("connection") if not str(c.get("from", "")).startswith(":")}
    missing = wanted - got
    extra = {c for c in got if c[0] in {w[0] for w in wanted} and c not in wanted}
    if missing or extra:
        raise RuntimeError(
            f"netconvert connections differ from the plan: missing {sorted(missing)}, extra {sorted(extra)}")


def _netconvert(directory: Path, geometry: HighwayGeometry, plan: _Plan) -> Path:
    """Write the plain XML of ``plan``, run netconvert on it and check its connections; the net file."""
    net_file = directory / "highway.net.xml"
    cmd = [
        sumo_binary("netconvert"), *_write_plain_xml(directory, geometry, plan),
        "--output-file", str(net_file), "--no-turnarounds", "true", "--no-warnings", "true",
        "--precision", "6",  # default 2 decimals would misplace lane centres by up to 5 mm
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"netconvert failed ({proc.returncode}): {proc.stderr.strip()}")
    _check_connections(net_file, plan)
    return net_file


def build_network(directory: Path, geometry: HighwayGeometry, layout: LayoutConfig | None = None) -> HighwayNetwork:
    """Build the network of ``geometry`` and ``layout`` (default straight) in ``directory`` and read it back."""
    lay = layout or LayoutConfig()
    plan = _plan(geometry, lay)
    net_file = _netconvert(directory, geometry, plan)

    straight_edges = {e[0] for e in plan.edges if not e[0].endswith("_ramp")}
    lanes = _lane_table(net_file, straight_edges)
    n = geometry.lanes_per_direction
    # Eastbound x range (all straight eastbound edges) tells where the road starts after netconvert's offset.
    east_x = [v for e, table in lanes.items() if e.startswith("E") for _, _, _, *xs in table for v in xs]
    x_start, x_end = min(east_x), max(east_x)
    window_x0 = x_start + 0.5 * (x_end - x_start - geometry.window_m)

    def main(east: bool) -> list[tuple[int, float, float, float, float]]:
        edge, first = plan.main_edge[east]
        return lanes[edge][first:first + n]

    def aux(east: bool) -> float:
        edge = plan.aux_edge.get(east)
        return float("nan") if edge is None else float(lanes[edge][0][1])

    def edges_y(table: list[tuple[int, float, float, float, float]]) -> np.ndarray:
        ys = np.sort([y + s * w / 2.0 for _, y, w, _, _ in table for s in (-1.0, 1.0)])
        # Adjacent lanes share a marking: merge edges closer than 5 cm (rounding in the file).
        groups = np.split(ys, np.flatnonzero(np.diff(ys) > 0.05) + 1)
        return np.asarray([g.mean() for g in groups])

    west_sumo = edges_y(main(False))  # larger SUMO y -> upper carriageway in the image
    east_sumo = edges_y(main(True))
    image_y_ref = geometry.image_top_m + float(west_sumo.max())
    return HighwayNetwork(
        net_file=net_file,
        geometry=geometry,
        layout=lay,
        window_x0_m=float(window_x0),
        image_y_ref_m=image_y_ref,
        east_centres_y_m=np.asarray([lane[1] for lane in main(True)]),
        west_centres_y_m=np.asarray([lane[1] for lane in main(False)]),
        upper_markings_y_m=np.sort(image_y_ref - west_sumo),
        lower_markings_y_m=np.sort(image_y_ref - east_sumo),
        east_aux_y_m=aux(True),
        west_aux_y_m=aux(False),
        routes=plan.routes,
        entries=plan.entries,
    )
