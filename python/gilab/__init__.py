"""gilab from Python: render, compare and run experiments on the same engine as the CLI.

    import gilab
    with gilab.Session("presets/cornell.toml", size=(64, 64)) as s:
        frame = s.render("restir", frames=8)
        ref = s.reference(spp=256)
        print(gilab.metrics.relmse(frame.image, ref))

Every call goes to the library functions the `gilab` commands use (`shot`, `reference`,
`compare`, `converge`); images are float32 numpy arrays (height, width, 3) in linear HDR.
Library errors raise `GilabError` (a RuntimeError) with the CLI's message; bad input raises
ValueError, missing files FileNotFoundError. The GIL is released while the GPU works.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _gilab, metrics
from ._gilab import GilabError
from ._progress import reporting

__all__ = [
    "Camera",
    "Frame",
    "Run",
    "GilabError",
    "Session",
    "converge",
    "metrics",
    "params",
    "read_exr",
    "techniques",
    "tonemap",
    "write_exr",
]

PathLike = Union[str, "os.PathLike[str]"]
Size = Union[int, Tuple[int, int], Sequence[int]]

#: Where references are cached, as the CLI's default (relative to the working directory).
DEFAULT_CACHE = os.path.join("cache", "reference")


def _toml_literal(value: Any) -> str:
    """A Python value as the TOML literal `--set key=value` takes (JSON's forms are TOML's)."""
    return json.dumps(value)


def _size_text(size: Optional[Size]) -> Optional[str]:
    if size is None:
        return None
    if isinstance(size, int):
        return str(size)
    w, h = size
    return f"{int(w)}x{int(h)}"


def _set_list(overrides: Optional[Mapping[str, Any]]) -> List[str]:
    return [f"{k}={_toml_literal(v)}" for k, v in (overrides or {}).items()]


def techniques() -> List[Dict[str, str]]:
    """The registered techniques: [{"id": ..., "what": ...}]."""
    return json.loads(_gilab.techniques_json())


def params(technique: str) -> List[Dict[str, Any]]:
    """A technique's parameters (the table `gilab params` prints): name, doc, higher, lower,
    kind (int/float/bool/choice), min, max, choices, default. Raises ValueError for an
    unknown technique."""
    return json.loads(_gilab.params_json(technique))


def read_exr(path: PathLike) -> np.ndarray:
    """A linear EXR as float32 (height, width, 3), read by the library's reader."""
    return _gilab.read_exr(os.fspath(path))


def write_exr(path: PathLike, image: np.ndarray) -> None:
    """Writes `image` as a linear EXR with the writer `gilab shot` uses."""
    _gilab.write_exr(os.fspath(path), metrics.as_image(image))


def _tonemap_json(operator: str, exposure: float, gt: Optional[Mapping[str, float]]) -> str:
    settings: Dict[str, Any] = {"operator": operator, "exposure": exposure}
    if gt:
        settings["gt"] = dict(gt)
    return json.dumps(settings)


def tonemap(
    image: np.ndarray,
    operator: str = "aces",
    exposure: float = 0.0,
    gt: Optional[Mapping[str, float]] = None,
) -> np.ndarray:
    """8-bit sRGB (height, width, 3) uint8 of the display transform the PNGs and the viewer use.

    operator: "aces", "reinhard", "linear" or "gt" (Uchimura; `gt` sets its parameters:
    max_brightness, contrast, linear_start, linear_length, black_tightness, pedestal);
    exposure in EV stops. Non-finite pixels show magenta."""
    return _gilab.tonemap_srgb8(metrics.as_image(image), _tonemap_json(operator, exposure, gt))


@dataclass
class Camera:
    """A pinhole camera: position, target, up (world space) and vertical field of view in degrees."""

    position: Tuple[float, float, float]
    target: Tuple[float, float, float]
    up: Tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov: float = 45.0

    def _json(self) -> str:
        return json.dumps(
            {
                "position": [float(v) for v in self.position],
                "target": [float(v) for v in self.target],
                "up": [float(v) for v in self.up],
                "fov_y": float(self.fov),
            }
        )

    @staticmethod
    def _from_json(text: str) -> "Camera":
        c = json.loads(text)
        return Camera(tuple(c["position"]), tuple(c["target"]), tuple(c["up"]), c["fov_y"])


@dataclass
class Frame:
    """The result of `Session.render`.

    image: float32 (height, width, 3) linear HDR radiance (denoised when denoise=True);
    variance: float32 (height, width, 3) per-pixel sample variance over the frames;
    samples: samples per pixel accumulated; timings: mean GPU ms per frame by pass
    (wall time where the adapter has no usable timestamps); rays: rays traced by kind;
    clock_check: the calibration kernel's drift around the render (with clock_check=True);
    meta: everything `gilab shot` writes to its JSON."""

    image: np.ndarray
    variance: np.ndarray
    meta: Dict[str, Any]
    clock_check: Optional[Dict[str, Any]] = None
    _debug: Dict[str, Tuple[np.ndarray, bool]] = field(default_factory=dict, repr=False)

    @property
    def samples(self) -> int:
        return int(self.meta["spp"])

    @property
    def frames(self) -> int:
        return int(self.meta["frames"])

    @property
    def timings(self) -> Dict[str, float]:
        return dict(self.meta["gpu_ms_by_pass"])

    @property
    def gpu_ms_per_frame(self) -> float:
        return float(self.meta["gpu_ms_per_frame"])

    @property
    def rays(self) -> Dict[str, int]:
        return dict(self.meta["rays_by_kind"])

    @property
    def rays_per_pixel(self) -> float:
        return float(self.meta["rays_per_pixel"])

    @property
    def debug_views(self) -> List[str]:
        """The technique's debug views (the viewer's), by name."""
        return list(self._debug)

    def debug(self, view: str) -> np.ndarray:
        """One debug view as float32 (height, width): the channel the viewer shows (ids are
        values, e.g. light or cell indices)."""
        try:
            return self._debug[view][0]
        except KeyError:
            views = ", ".join(self._debug) or "none"
            raise ValueError(
                f"no debug view '{view}' for technique '{self.meta['technique']}' (it has: {views})"
            ) from None

    def __repr__(self) -> str:
        h, w = self.image.shape[:2]
        return (
            f"<gilab.Frame {self.meta['label']} {w}x{h}, {self.frames} frames, {self.samples} spp, "
            f"{self.gpu_ms_per_frame:.2f} ms/frame, {self.rays_per_pixel:.2f} rays/px>"
        )

    def save(self, path: PathLike, operator: Optional[str] = None, exposure: float = 0.0) -> None:
        """Writes the image as `gilab shot` does: `.exr` linear, `.png` tonemapped (the
        preset's display transform unless `operator` is given)."""
        path = os.fspath(path)
        if path.lower().endswith(".exr"):
            _gilab.write_exr(path, self.image)
        elif path.lower().endswith(".png"):
            tm = self.meta["preset"].get("tonemap")
            settings = json.dumps(tm) if operator is None else _tonemap_json(operator, exposure, None)
            _gilab.write_png(path, self.image, settings)
        else:
            raise ValueError(f"{path}: expected a .exr or .png file name")


def _frame(out: Dict[str, Any]) -> Frame:
    check = out["clock_check_json"]
    return Frame(
        image=out["image"],
        variance=out["variance"],
        meta=json.loads(out["meta_json"]),
        clock_check=None if check is None else json.loads(check),
        _debug=dict(out["debug"]),
    )


def _event(material=None, emissive=None, base_color=None, roughness=None, metallic=None,
           light=None, position=None, intensity=None) -> Dict[str, Any]:
    event: Dict[str, Any] = {}
    for key, value in (("material", material), ("light", light)):
        if value is not None:
            event[key] = value
    for key, value in (("emissive", emissive), ("base_color", base_color),
                       ("position", position), ("intensity", intensity)):
        if value is not None:
            event[key] = [float(v) for v in value]
    for key, value in (("roughness", roughness), ("metallic", metallic)):
        if value is not None:
            event[key] = float(value)
    return event


class Run:
    """One technique's engine kept across calls (from `Session.start`): each `step` renders
    more frames on it, accumulating as the engine does (or, for a real-time technique, carrying
    its history), and edits land mid-run as `converge`'s events do. `run.step(2); run.step(1)`
    gives the pixels of `session.render(t, frames=3)`. The run keeps the device alive until it
    is dropped. Use it from the thread that made it."""

    def __init__(self, run: "_gilab.Run") -> None:
        self._r = run

    def step(self, frames: int = 1, clock_check: bool = False, progress: bool = False) -> Frame:
        """Renders `frames` more frames; the Frame holds everything since the start or reset
        (samples, rays; timings are this step's mean per frame)."""
        if isinstance(frames, bool) or int(frames) < 1:
            raise ValueError("frames must be a positive integer")
        with reporting(progress):
            return _frame(self._r.step(int(frames), bool(clock_check), bool(progress)))

    @property
    def frames(self) -> int:
        """Frames since the start or the last reset."""
        return self._r.frames

    def reset(self) -> None:
        """Forgets history, accumulation and counters (a camera cut)."""
        self._r.reset()

    @property
    def camera(self) -> Camera:
        """The run's camera; assigning one is a scripted camera move (accumulation restarts,
        reuse history carries on)."""
        return Camera._from_json(self._r.camera_json())

    @camera.setter
    def camera(self, camera: Union[Camera, Mapping[str, Any]]) -> None:
        if isinstance(camera, Mapping):
            camera = Camera(**camera)
        self._r.move_camera_json(camera._json())

    def edit_material(self, name: str, **fields: Any) -> None:
        """A material edit now (emissive, base_color, roughness, metallic), as an event."""
        self.apply_event(_event(material=name, **fields))

    def edit_light(self, index: int, **fields: Any) -> None:
        """A punctual-light edit now (position, intensity), as an event."""
        self.apply_event(_event(light=int(index), **fields))

    def apply_event(self, event: Mapping[str, Any]) -> None:
        """An `[[experiment.event]]` table's change applied before the next frame (`frame`
        is ignored): the edited scene is swapped in, the engine's history carries on."""
        self._r.apply_event_json(json.dumps(dict(event)))


class Session:
    """One GPU device and a loaded scene; renders any technique on it.

    preset: a preset file (default: the built-in Cornell box, as the CLI); or a dict with a
    preset's tables. scene: a built-in scene name or a glTF path (`--scene`). size: N or
    (width, height) (`--size`). backend: "vulkan", "gl" or None (auto; also GILAB_BACKEND).
    overrides: any preset key, as `--set key=value` ({"render.seed": 3,
    "scene.params.albedo": 0.5}). Use it in a `with` block, or call close(), to release the
    device."""

    def __init__(
        self,
        preset: Union[PathLike, Mapping[str, Any], None] = None,
        scene: Optional[str] = None,
        size: Optional[Size] = None,
        backend: Optional[str] = None,
        overrides: Optional[Mapping[str, Any]] = None,
    ) -> None:
        path, table = None, None
        if isinstance(preset, Mapping):
            table = json.dumps(preset)
        elif preset is not None:
            path = os.fspath(preset)
        self._s = _gilab.Session(
            path, table, scene, _size_text(size), _set_list(overrides), backend
        )

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Releases the GPU device; the session cannot render afterwards."""
        self._s.close()

    @property
    def closed(self) -> bool:
        return self._s.closed

    @property
    def size(self) -> Tuple[int, int]:
        """(width, height) of every render."""
        return self._s.size

    @property
    def seed(self) -> int:
        """The preset's seed: what render(seed=None) uses, as `gilab shot`."""
        return self._s.seed

    @property
    def scene_name(self) -> str:
        return self._s.scene_name

    @property
    def adapter(self) -> Dict[str, Any]:
        """The GPU adapter (name, backend, driver)."""
        return json.loads(self._s.adapter_json())

    @property
    def preset(self) -> Dict[str, Any]:
        """The preset as the session holds it (overrides, camera and edits applied)."""
        return json.loads(self._s.preset_json())

    @property
    def scene_features(self) -> Dict[str, Any]:
        """What the scene has (triangles, lights, materials, BVH depth ...)."""
        return json.loads(self._s.scene_features_json())

    def techniques(self) -> List[Dict[str, str]]:
        """The registered techniques: [{"id": ..., "what": ...}]."""
        return techniques()

    def params(self, technique: str) -> List[Dict[str, Any]]:
        """A technique's parameter specs with ranges and docs (see `gilab.params`)."""
        return params(technique)

    @property
    def camera(self) -> Camera:
        """The camera renders and references use; assign a Camera (or a dict with position,
        target, up, fov) to move it."""
        return Camera._from_json(self._s.camera_json())

    @camera.setter
    def camera(self, camera: Union[Camera, Mapping[str, Any]]) -> None:
        if isinstance(camera, Mapping):
            camera = Camera(**camera)
        self._s.set_camera_json(camera._json())

    def set(self, key: str, value: Any) -> None:
        """Sets a preset key as `--set key=value` does (`render.reference_spp`, `tonemap.exposure`,
        `scene.params.albedo`, ...); a `scene.` key loads the scene again (the session's edits
        are applied to it again; the camera stays where it is: assign `camera` to move it)."""
        self._s.set_preset_value(key, _toml_literal(value))

    def set_scene_param(self, name: str, value: Any) -> None:
        """Sets a built-in scene's parameter (`scene.params.NAME`) and loads the scene again."""
        self.set(f"scene.params.{name}", value)

    def edit_material(
        self,
        name: str,
        emissive: Optional[Sequence[float]] = None,
        base_color: Optional[Sequence[float]] = None,
        roughness: Optional[float] = None,
        metallic: Optional[float] = None,
    ) -> None:
        """A scripted material edit (an experiment's event): emissive switches a light on or
        off. Renders after this see the edited scene; references key on the edits."""
        self.apply_event(_event(material=name, emissive=emissive, base_color=base_color,
                                roughness=roughness, metallic=metallic))

    def edit_light(
        self,
        index: int,
        position: Optional[Sequence[float]] = None,
        intensity: Optional[Sequence[float]] = None,
    ) -> None:
        """A scripted punctual-light edit: move it, or change its intensity (0 switches it off)."""
        self.apply_event(_event(light=int(index), position=position, intensity=intensity))

    def apply_event(self, event: Mapping[str, Any]) -> None:
        """Applies an `[[experiment.event]]` table's change (material, light or camera fields;
        `frame` is ignored) to the session's scene."""
        self._s.apply_event_json(json.dumps(dict(event)))

    @property
    def events(self) -> List[Dict[str, Any]]:
        """The scene edits applied so far."""
        return json.loads(self._s.events_json())

    def render(
        self,
        technique: str,
        frames: int = 1,
        seed: Optional[int] = None,
        params: Optional[Mapping[str, Any]] = None,
        denoise: bool = False,
        budget: Optional[float] = None,
        clock_check: bool = False,
        progress: bool = False,
    ) -> Frame:
        """Renders `frames` frames of `technique` on a fresh engine, as `gilab shot` does
        (`gilab shot --technique T --seed S --spp frames*samples_per_frame` gives the same
        pixels).

        seed: None uses the preset's seed. params: the technique's parameters (checked against
        their ranges: ValueError). denoise: run the shared SVGF-style denoiser. budget: a ray
        budget in rays per pixel per frame, mapped as the viewer's slider does. clock_check:
        warm up the calibration kernel first and measure its drift after (as converge does).
        """
        if isinstance(frames, bool) or int(frames) < 1:
            raise ValueError("frames must be a positive integer")
        with reporting(progress):
            out = self._s.render(
                technique,
                int(frames),
                None if seed is None else int(seed),
                json.dumps(dict(params or {})),
                bool(denoise),
                None if budget is None else float(budget),
                bool(clock_check),
                bool(progress),
            )
        return _frame(out)

    def start(
        self,
        technique: str,
        seed: Optional[int] = None,
        params: Optional[Mapping[str, Any]] = None,
        denoise: bool = False,
        budget: Optional[float] = None,
    ) -> "Run":
        """An engine for `technique` kept across calls (`Run.step`), for per-frame curves and
        edits in the middle of a run (lag). Same arguments as `render`."""
        return Run(
            self._s.start(
                technique,
                None if seed is None else int(seed),
                json.dumps(dict(params or {})),
                bool(denoise),
                None if budget is None else float(budget),
            )
        )

    @property
    def entries(self) -> List[Dict[str, Any]]:
        """The preset's `[[techniques]]` entries (name, label, params, budget, denoise)."""
        return self.preset["techniques"]

    def render_entry(self, label: str, frames: Optional[int] = None, **kwargs: Any) -> Frame:
        """Renders the preset's entry `label` (its label, else its technique name) with its
        parameters, ray budget and denoiser, as `gilab shot PRESET` renders it; `frames`
        defaults to the preset's `render.spp` over the technique's samples per frame."""
        matches = [e for e in self.entries if e.get("label", e["name"]) == label]
        if not matches:
            known = ", ".join(e.get("label", e["name"]) for e in self.entries)
            raise ValueError(f"the preset has no technique entry '{label}' (it has: {known})")
        entry = matches[0]
        if frames is None:
            specs = {p["name"]: p for p in params(entry["name"])}
            spf = entry.get("params", {}).get(
                "samples_per_frame", specs.get("samples_per_frame", {}).get("default", 1)
            )
            spp = self.preset["render"]["spp"]
            frames = max(1, -(-spp // max(1, int(spf))))
        kwargs.setdefault("denoise", entry.get("denoise", False))
        kwargs.setdefault("budget", entry.get("budget"))
        kwargs.setdefault("params", entry.get("params", {}))
        return self.render(entry["name"], frames=frames, **kwargs)

    def reference(
        self,
        spp: Optional[int] = None,
        cache: PathLike = DEFAULT_CACHE,
        force: bool = False,
        progress: bool = True,
    ) -> np.ndarray:
        """The converged reference of the session's scene and camera, cached as `gilab
        reference` caches it (same key, same file): `spp` samples (None: the preset's
        `render.reference_spp`), rendered only when the cache misses (or `force`)."""
        with reporting(progress):
            image, _ = self._s.reference(spp, os.fspath(cache), bool(force), bool(progress))
        return image

    def reference_path(self, spp: Optional[int] = None, cache: PathLike = DEFAULT_CACHE) -> str:
        """The EXR file `reference(spp)` reads or writes."""
        return self._s.reference_path(spp, os.fspath(cache))

    def __repr__(self) -> str:
        state = "closed" if self.closed else f"{self.size[0]}x{self.size[1]}"
        return f"<gilab.Session scene={self.scene_name!r} {state}>"


def converge(
    experiment: Union[PathLike, Mapping[str, Any]],
    out: Optional[PathLike] = None,
    cache: PathLike = DEFAULT_CACHE,
    overrides: Optional[Mapping[str, Any]] = None,
    backend: Optional[str] = None,
    progress: bool = True,
    as_frame: Optional[bool] = None,
) -> Tuple[Dict[str, Any], Any]:
    """Runs a convergence experiment as `gilab converge FILE --out OUT` does (the same report,
    CSV, JSON and plots in `out`, default out/converge/<name>), and returns (summary,
    rows): the summary.json dict and the per-frame rows of convergence.csv, as a pandas
    DataFrame when pandas is installed (as_frame=None) or a list of dicts.

    experiment: an experiment preset file, or a dict with the same tables."""
    path, table = None, None
    if isinstance(experiment, Mapping):
        table = json.dumps(experiment)
    else:
        path = os.fspath(experiment)
    with reporting(progress):
        out_dir, rows = _gilab.converge(
            path,
            table,
            None if out is None else os.fspath(out),
            os.fspath(cache),
            _set_list(overrides),
            backend,
            not progress,
        )
    with open(os.path.join(out_dir, "summary.json")) as f:
        summary = json.load(f)
    rows_list = json.loads(rows)
    if as_frame is None or as_frame:
        try:
            import pandas as pd
        except ImportError:
            if as_frame:
                raise
        else:
            return summary, pd.DataFrame(rows_list)
    return summary, rows_list
