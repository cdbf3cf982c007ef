"""Results of the methods that draw no random numbers, kept on disk by content (``--cache DIR``).

A real-site evaluation runs every comparison method (trilateration, wcl, drssi, markov) on
every (calibration, scored run) pair; markov alone is most of the cost of ``make eval-sites``,
and none of them changes while the default method is being developed. A result is stored under
the SHA-256 of everything it depends on: the method, its options and odometry flag, the scored
sequence (times, RSSI, reading counts, odometry, ground truth), the site it ran with (radio
model, anchors, heights, every table: the calibration), and the source of every pfdoa module
the method's own module imports, directly or not, with the scoring code's and numpy's version
(:func:`code_digest`; the code that made the sequence is not keyed: its output is). Change
any of them and the result is computed again; nothing is ever looked up by name or date. A
method that draws random numbers (pf-doa, pf-doa-paper) is never cached: those are what changes.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import hashlib
import importlib.util
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from pfdoa.evaluation.runner import RunResult

log = logging.getLogger(__name__)

FORMAT = "pfdoa-eval-cache 3"
OPTIONAL = ("in_cov", "lost", "r95_m")


def _module_file(name: str) -> Path | None:
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    origin = spec.origin if spec is not None else None
    return Path(origin) if origin and origin.endswith(".py") else None


def _imports(path: Path) -> set[str]:
    """The pfdoa modules ``path`` imports, at module level or inside functions."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "pfdoa")
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "pfdoa":
            module = str(node.module)
            out.add(module)
            out.update(f"{module}.{a.name}" for a in node.names if _module_file(f"{module}.{a.name}") is not None)
    return out


@functools.lru_cache(maxsize=None)
def code_digest(module: str) -> str:
    """SHA-256 over the source of ``module`` and of every pfdoa module it imports, transitively
    (:func:`code_modules`), and numpy's version."""
    h = hashlib.sha256(f"{FORMAT} numpy {np.__version__}".encode())
    for m, digest in sorted(code_modules(module).items()):
        h.update(f"{m} {digest}\n".encode())
    return h.hexdigest()


def code_modules(module: str, follow: bool = True) -> dict[str, str]:
    """{module: SHA-256 of its source} for ``module`` and (``follow``) every pfdoa module it
    imports, transitively (a package's ``__init__`` is hashed but not followed: importing
    ``pfdoa.estimators.markov`` runs the package's init, which imports every method, but markov
    uses none of them)."""
    seen: dict[str, str] = {}
    stack = [module]
    while stack:
        m = stack.pop()
        if m in seen:
            continue
        f = _module_file(m)
        if f is None:
            continue
        seen[m] = hashlib.sha256(f.read_bytes()).hexdigest()
        if follow and f.name != "__init__.py":
            stack.extend(_imports(f))
    return seen


@functools.lru_cache(maxsize=None)
def method_module(method: str) -> str:
    """The module that implements ``method`` (built once on the paper's simulated room)."""
    from pfdoa.estimators import make_estimator
    from pfdoa.evaluation.datasets import d0_site

    return type(make_estimator(method, d0_site(), rng=np.random.default_rng(0))).__module__


def _feed(h: Any, obj: Any, depth: int = 0) -> None:
    """Feed ``obj`` into ``h`` canonically: arrays whole (dtype, shape, bytes), dicts in key order,
    dataclasses field by field."""
    if depth > 32:
        raise ValueError("nested too deeply to key a cache entry")
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(f"nd {a.dtype.str} {a.shape}".encode())
        h.update(a.tobytes())
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(f"dc {type(obj).__qualname__}".encode())
        for f in dataclasses.fields(obj):
            h.update(f.name.encode())
            _feed(h, getattr(obj, f.name), depth + 1)
    elif isinstance(obj, dict):
        h.update(f"dict {len(obj)}".encode())
        for k in sorted(obj, key=repr):
            _feed(h, k, depth + 1)
            _feed(h, obj[k], depth + 1)
    elif isinstance(obj, (list, tuple)):
        h.update(f"{type(obj).__name__} {len(obj)}".encode())
        for v in obj:
            _feed(h, v, depth + 1)
    elif obj is None or isinstance(obj, (bool, int, float, str, np.generic)):
        h.update(f"{type(obj).__name__} {obj!r};".encode())
    else:
        raise TypeError(f"cannot key a cache entry on a {type(obj).__name__}")


def key(variant, seq) -> str:
    """The cache key of ``variant`` run over ``seq`` (see the module doc)."""
    h = hashlib.sha256(FORMAT.encode())
    _feed(h, (variant.method, tuple(sorted(variant.options, key=repr)), bool(variant.use_odometry)))
    # The scoring is runner.py's own code (with the estimators' base module, in the method's
    # closure); the code that made the sequence does not matter, its output is hashed below.
    _feed(h, (code_digest(method_module(variant.method)), code_modules("pfdoa.evaluation.runner", follow=False)))
    odometry = None if seq.odometry is None else np.array([[o.dx, o.dy, o.dtheta] for o in seq.odometry], dtype=float)
    _feed(h, (seq.t, seq.rssi, seq.truth, seq.count, odometry, seq.beacon, seq.site))
    return h.hexdigest()


def load(folder: str, k: str) -> RunResult | None:
    path = Path(folder) / k[:2] / f"{k}.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            r = RunResult(z["errors"], z["step_ms"], z["estimates"], int(z["held"]))
            for name in OPTIONAL:
                if name in z.files:
                    setattr(r, name, z[name])
            return r
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError) as exc:  # a damaged entry: computed again and rewritten
        log.warning("eval cache: %s unreadable (%s): computed again", path, exc)
        return None


def store(folder: str, k: str, r: RunResult) -> None:
    """Write an entry atomically (two workers may write the same one: the same bytes)."""
    path = Path(folder) / k[:2] / f"{k}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    arrays: dict[str, Any] = {"errors": r.errors, "step_ms": r.step_ms, "estimates": r.estimates,
                              "held": np.array(r.held)}
    arrays.update({name: getattr(r, name) for name in OPTIONAL if getattr(r, name) is not None})
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(tmp, path)
