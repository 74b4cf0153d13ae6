"""One SUMO instance per process, reloaded per lane layout: libsumo (in-process, one per process) or TraCI (a
subprocess; the GUI). libsumo's harmless pyarrow warning on import is swallowed."""

from __future__ import annotations

import contextlib
import io
import shutil
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import Any

from letspi.constants import DT_S
from letspi.simulation.config import ClosedLoopConfig
from letspi.simulation.network import LayoutKey, NetworkCache, SlotNetwork
from letspi.trafficgen.binaries import sumo_binary


class SumoSessionError(RuntimeError):
    """SUMO could not be started or loaded."""


def import_libsumo() -> ModuleType:
    """``libsumo``, imported without its pyarrow version warning (see module doc)."""
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            import libsumo
    except ImportError as exc:
        raise SumoSessionError("closed-loop runs need libsumo (pip install libsumo==1.28.0)") from exc
    return libsumo


def import_traci() -> ModuleType:
    try:
        import traci
    except ImportError as exc:
        raise SumoSessionError("the traci backend needs the traci package (pip install traci)") from exc
    return traci


def sumo_arguments(net: SlotNetwork, config: ClosedLoopConfig) -> list[str]:
    """Command-line options of every closed-loop simulation (without the binary)."""
    return [
        "--net-file", str(net.net_file), "--route-files", str(net.route_file), "--begin", "0",
        "--step-length", f"{DT_S}", "--lateral-resolution", f"{config.lateral_resolution_m}",
        # physical contact only (mingap factor 0); keep colliding vehicles so both sides are scored
        "--collision.mingap-factor", "0", "--collision.action", "warn", "--collision.check-junctions", "false",
        "--time-to-teleport", "-1", "--seed", "0", "--no-step-log", "true", "--no-warnings", "true",
        "--duration-log.disable", "true",
    ]  # fmt: skip


class SumoSession:
    """A SUMO instance that (re)loads slot networks (a context manager); ``open(widths, n_slots)`` returns a network
    with a clean simulation at time 0."""

    def __init__(self, config: ClosedLoopConfig, work_dir: Path | None = None) -> None:
        self.config = config
        self._tmp: str | None = None
        if work_dir is None:
            self._tmp = tempfile.mkdtemp(prefix="letspi-simulation-")
            work_dir = Path(self._tmp)
        self.networks = NetworkCache(work_dir, config)
        self.api: Any = None
        self.loads = 0
        self.load_s = 0.0
        self._started = False

    def _start(self, args: list[str]) -> None:
        cfg = self.config
        if cfg.sumo_gui or cfg.sumo_backend == "traci":
            traci = import_traci()
            binary = sumo_binary("sumo-gui" if cfg.sumo_gui else "sumo")
            extra = ["--start", "true", "--quit-on-end", "true"] if cfg.sumo_gui else []
            traci.start([binary, *args, *extra])
            self.api = traci
        else:
            libsumo = import_libsumo()
            if libsumo.simulation.isLoaded():
                raise SumoSessionError("libsumo already runs a simulation in this process (one per process): "
                                       "close the other session, or run closed loop in worker processes")
            libsumo.start([sumo_binary("sumo"), *args])
            self.api = libsumo
        self._started = True

    def open(self, widths: LayoutKey, n_slots: int) -> SlotNetwork:
        net = self.networks.get(widths, n_slots)
        args = sumo_arguments(net, self.config)
        t0 = time.perf_counter()
        try:
            if not self._started:
                self._start(args)
            else:
                self.api.load(args)
        except SumoSessionError:
            raise
        except Exception as exc:  # libsumo raises its own exception types
            raise SumoSessionError(f"SUMO failed to load {net.net_file}: {exc}") from exc
        self.load_s += time.perf_counter() - t0
        self.loads += 1
        return net

    def close(self) -> None:
        if self._started and self.api is not None:
            with contextlib.suppress(Exception):
                self.api.close()
        self._started = False
        self.api = None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> SumoSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
