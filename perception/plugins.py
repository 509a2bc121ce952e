"""Point-encoder plug-ins (the geometric foundation model Psi of paper Alg. 1).

GeoTransformer, GeDi and BUFFER-X ship no installable packages, so kitchenbot does not bundle them; a user
wraps the one they have in a class with this interface and names it in the config
(``perception.point_encoder``):

    class MyEncoder:
        name = "gedi"        # identifies the features: the CAD feature database cache is keyed by it
        dim = 32             # feature length
        def encode(self, points, normals, voxel):   # (M, 3) voxel centres (m), (M, 3) unit normals, voxel (m)
            return features                          # (M, dim) float array, one row per point, finite

The constructor takes no arguments (read your own weights path from an environment variable or a
file next to your module). Three ways to make the name resolve:

1. a ``module:Class`` string in the config:  ``point_encoder: my_package.gedi_wrapper:GeDiEncoder``;
2. a Python entry point in the group ``kitchenbot.point_encoders`` of your package's pyproject.toml:
       [project.entry-points."kitchenbot.point_encoders"]
       gedi = "my_package.gedi_wrapper:GeDiEncoder"
   then ``point_encoder: gedi``;
3. at run time: ``register_point_encoder("gedi", GeDiEncoder)`` before the Perceiver is built.

Every loaded encoder is checked once on a small synthetic cloud (shape, finiteness) so a broken plug-in
fails at start-up with its name in the message, not in the middle of a scan.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Callable

import numpy as np

from kitchenbot.perception.features import POINT_ENCODERS, PointEncoder

ENTRY_POINT_GROUP = "kitchenbot.point_encoders"


class PluginError(ValueError):
    """A point-encoder name that does not resolve, or a plug-in that does not keep the interface."""


def register_point_encoder(name: str, factory: Callable[[], PointEncoder]) -> None:
    """Make `name` resolve to `factory()` in this process."""
    if not name or ":" in name:
        raise PluginError(f"register_point_encoder: name {name!r} must be non-empty and contain no ':'")
    POINT_ENCODERS[name] = factory


def _entry_points() -> dict[str, object]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def point_encoder_names() -> dict[str, str]:
    """Every name that resolves without a `module:Class` string -> where it comes from."""
    out = {n: "built-in" if n == "fpfh" else "registered" for n in POINT_ENCODERS}
    for n, ep in _entry_points().items():
        out.setdefault(n, f"entry point {ep.value}")
    return out


def _factory(name: str) -> Callable[[], PointEncoder]:
    if name in POINT_ENCODERS:
        return POINT_ENCODERS[name]
    eps = _entry_points()
    if name in eps:
        try:
            return eps[name].load()
        except Exception as e:  # noqa: BLE001 - any import failure of a third-party plug-in
            raise PluginError(f"perception.point_encoder {name!r}: entry point {eps[name].value} did not load: "
                              f"{type(e).__name__}: {e}") from e
    if ":" in name:
        mod, _, attr = name.partition(":")
        try:
            module = importlib.import_module(mod)
        except ImportError as e:
            raise PluginError(f"perception.point_encoder {name!r}: cannot import module {mod!r} ({e})") from e
        obj = module
        for part in attr.split("."):
            if not hasattr(obj, part):
                raise PluginError(f"perception.point_encoder {name!r}: module {mod!r} has no attribute {attr!r}")
            obj = getattr(obj, part)
        return obj  # type: ignore[return-value]
    have = sorted(point_encoder_names())
    raise PluginError(f"perception.point_encoder: unknown encoder {name!r}; choose one of {', '.join(have)}, "
                      f"a 'module:Class' string, or install a plug-in in the entry-point group {ENTRY_POINT_GROUP!r}")


def check_point_encoder(enc: object, label: str) -> PointEncoder:
    """Raise PluginError unless `enc` keeps the PointEncoder interface on a small synthetic cloud."""
    for attr in ("name", "dim", "encode"):
        if not hasattr(enc, attr):
            raise PluginError(f"perception.point_encoder {label!r}: the plug-in has no {attr!r} (needs name, dim, encode)")
    if not isinstance(enc.name, str) or not enc.name:
        raise PluginError(f"perception.point_encoder {label!r}: .name must be a non-empty string")
    if not isinstance(enc.dim, (int, np.integer)) or enc.dim <= 0:
        raise PluginError(f"perception.point_encoder {label!r}: .dim must be a positive int, got {enc.dim!r}")
    # a 6 cm x 4 cm patch of a gently curved surface at 5 mm spacing: 117 points
    u, v = np.meshgrid(np.linspace(-0.03, 0.03, 13), np.linspace(-0.02, 0.02, 9))
    P = np.stack([u.ravel(), v.ravel(), 2.0 * (u.ravel() ** 2)], 1)
    N = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    try:
        F = np.asarray(enc.encode(P, N, 0.005))
    except Exception as e:  # noqa: BLE001 - report any failure of third-party code with the plug-in's name
        raise PluginError(f"perception.point_encoder {label!r}: encode() failed on a test cloud: "
                          f"{type(e).__name__}: {e}") from e
    if F.shape != (len(P), int(enc.dim)):
        raise PluginError(f"perception.point_encoder {label!r}: encode() returned shape {F.shape}, "
                          f"expected ({len(P)}, {enc.dim}) (one row of length dim per point)")
    if not np.all(np.isfinite(F)):
        raise PluginError(f"perception.point_encoder {label!r}: encode() returned non-finite values")
    return enc  # type: ignore[return-value]


def load_point_encoder(name: str) -> PointEncoder:
    """The point encoder a config names: built-in, registered, entry point, or `module:Class`."""
    factory = _factory(name)
    try:
        enc = factory()
    except Exception as e:  # noqa: BLE001
        raise PluginError(f"perception.point_encoder {name!r}: constructing it failed: {type(e).__name__}: {e}") from e
    return check_point_encoder(enc, name)
