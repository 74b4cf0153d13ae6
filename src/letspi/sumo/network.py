"""Straight two-direction highway built with SUMO's ``netconvert`` from plain XML.

Layout (SUMO coordinates, metres, y pointing **up**)::

    y = median + n*w  ───────────────────────────────  upper road edge (direction 1, towards -x)
                      <──── westbound lanes (edge "W")
    y = median        ───────────────────────────────
                      (median strip)
    y = 0             ───────────────────────────────
                      ────> eastbound lanes (edge "E")   (direction 2, towards +x)
    y = -n*w          ───────────────────────────────  lower road edge

The road is ``2 * approach_m + window_m`` long so that both directions drive the same
``approach_m`` warm-up stretch before reaching the recorded window in the middle. Lane positions
are always read back from the generated ``.net.xml`` (netconvert may shift coordinates).
"""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from letspi.sumo.binaries import sumo_binary

EASTBOUND_EDGE = "E"  # HighD drivingDirection 2 (towards +x, lower lanes)
WESTBOUND_EDGE = "W"  # HighD drivingDirection 1 (towards -x, upper lanes)


@dataclass(frozen=True)
class HighwayGeometry:
    """Design parameters of the generated highway.

    Attributes:
        lanes_per_direction: lanes on each carriageway (2 or 3).
        lane_width_m: lane width [m] (German autobahn: 3.5-3.75 m).
        median_m: distance between the two inner road edges [m].
        approach_m: warm-up stretch driven before the window, per direction [m].
        window_m: length of the recorded window [m] (HighD: about 420 m).
        lane_speed_mps: lane speed in SUMO [m/s]; set high to model an unrestricted autobahn,
            vehicles are limited by their own ``desiredMaxSpeed``.
        image_top_m: image y [m] given to the upper road edge (HighD images start at a few metres).
    """

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
class HighwayNetwork:
    """The generated network, as read back from the ``.net.xml``.

    Attributes:
        net_file: path of the ``.net.xml`` (inside a temporary directory).
        geometry: the design parameters it was built from.
        window_x0_m: SUMO x [m] of the window's left end (image x = SUMO x - window_x0_m).
        image_y_ref_m: image y = image_y_ref_m - SUMO y [m].
        east_centres_y_m: SUMO y of the eastbound lane centres, by SUMO lane index (0 = rightmost).
        west_centres_y_m: same for the westbound lanes.
        upper_markings_y_m: image y of the upper carriageway markings, ascending (edges included).
        lower_markings_y_m: image y of the lower carriageway markings, ascending (edges included).
    """

    net_file: Path
    geometry: HighwayGeometry
    window_x0_m: float
    image_y_ref_m: float
    east_centres_y_m: np.ndarray
    west_centres_y_m: np.ndarray
    upper_markings_y_m: np.ndarray
    lower_markings_y_m: np.ndarray


def _write_plain_xml(directory: Path, geometry: HighwayGeometry) -> tuple[Path, Path]:
    length = geometry.road_length_m
    nodes = directory / "highway.nod.xml"
    edges = directory / "highway.edg.xml"
    # Separate node pairs per direction: the median is simply the y distance between them
    # (netconvert spreads each edge's lanes to its right-hand side).
    nodes.write_text(
        "<nodes>\n"
        f'  <node id="e0" x="0" y="0"/>\n  <node id="e1" x="{length:.3f}" y="0"/>\n'
        f'  <node id="w0" x="{length:.3f}" y="{geometry.median_m:.3f}"/>\n'
        f'  <node id="w1" x="0" y="{geometry.median_m:.3f}"/>\n'
        "</nodes>\n"
    )
    common = (
        f'numLanes="{geometry.lanes_per_direction}" speed="{geometry.lane_speed_mps:.2f}" '
        f'width="{geometry.lane_width_m:.3f}"'
    )
    edges.write_text(
        "<edges>\n"
        f'  <edge id="{EASTBOUND_EDGE}" from="e0" to="e1" {common}/>\n'
        f'  <edge id="{WESTBOUND_EDGE}" from="w0" to="w1" {common}/>\n'
        "</edges>\n"
    )
    return nodes, edges


def _lane_table(net_file: Path) -> dict[str, list[tuple[int, float, float, float, float]]]:
    """Per edge: (index, y of the centre line [m], width [m], x start, x end) for each lane."""
    out: dict[str, list[tuple[int, float, float, float, float]]] = {}
    for edge in ET.parse(net_file).getroot().iter("edge"):
        if edge.get("function") == "internal":
            continue
        lanes = []
        for lane in edge.iter("lane"):
            pts = [tuple(float(c) for c in p.split(",")) for p in lane.get("shape", "").split()]
            ys = {round(p[1], 6) for p in pts}
            if len(ys) != 1:
                raise RuntimeError(f"lane {lane.get('id')} is not straight along x: {pts}")
            lanes.append((int(lane.get("index", "0")), pts[0][1], float(lane.get("width", "3.2")),
                          pts[0][0], pts[-1][0]))
        out[str(edge.get("id"))] = sorted(lanes)
    return out


def build_network(directory: Path, geometry: HighwayGeometry) -> HighwayNetwork:
    """Write plain XML into ``directory``, run netconvert and read the lane layout back.

    Args:
        directory: an existing (temporary) directory that receives the files.
        geometry: design parameters.

    Returns:
        The network description with the SUMO -> HighD image transform.
    """
    nodes, edges = _write_plain_xml(directory, geometry)
    net_file = directory / "highway.net.xml"
    cmd = [
        sumo_binary("netconvert"), "--node-files", str(nodes), "--edge-files", str(edges),
        "--output-file", str(net_file), "--no-turnarounds", "true", "--no-warnings", "true",
        "--precision", "6",  # default 2 decimals would misplace lane centres by up to 5 mm
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"netconvert failed ({proc.returncode}): {proc.stderr.strip()}")

    lanes = _lane_table(net_file)
    east, west = lanes[EASTBOUND_EDGE], lanes[WESTBOUND_EDGE]
    # Eastbound lane x range tells where the road starts after netconvert's offset.
    x_start = min(lane[3] for lane in east)
    x_end = max(lane[4] for lane in east)
    window_x0 = x_start + 0.5 * (x_end - x_start - geometry.window_m)

    def edges_y(table: list[tuple[int, float, float, float, float]]) -> np.ndarray:
        ys = np.sort([y + s * w / 2.0 for _, y, w, _, _ in table for s in (-1.0, 1.0)])
        # Adjacent lanes share a marking: merge edges closer than 5 cm (rounding in the file).
        groups = np.split(ys, np.flatnonzero(np.diff(ys) > 0.05) + 1)
        return np.asarray([g.mean() for g in groups])

    west_sumo = edges_y(west)  # larger SUMO y -> upper carriageway in the image
    east_sumo = edges_y(east)
    image_y_ref = geometry.image_top_m + float(west_sumo.max())
    return HighwayNetwork(
        net_file=net_file,
        geometry=geometry,
        window_x0_m=float(window_x0),
        image_y_ref_m=image_y_ref,
        east_centres_y_m=np.asarray([lane[1] for lane in east]),
        west_centres_y_m=np.asarray([lane[1] for lane in west]),
        upper_markings_y_m=np.sort(image_y_ref - west_sumo),
        lower_markings_y_m=np.sort(image_y_ref - east_sumo),
    )
