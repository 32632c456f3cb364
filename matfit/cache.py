"""Compile once per machine: JAX's persistent compilation cache for matfit.

XLA compiles every solver and kernel the first time a process calls it, and for a short fit the
compilation is most of the work. With the persistent cache the compiled executables are written
to disk and a later process with the same program (same family, method, loss, dtype and table
shape) loads them instead of compiling again.

The command line (``matfit ...``) and the demo switch it on. Library users call
:func:`enable_compilation_cache` once, before their first fit:

    import matfit.cache
    matfit.cache.enable_compilation_cache()

Where the cache lives: ``$MATFIT_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/matfit/jax``
(``~/.cache/matfit/jax``). ``MATFIT_NO_CACHE=1`` turns it off. JAX keys every entry on the
program, the compile options, the JAX and XLA versions and the device, so a stale entry is never
used; deleting the folder is always safe.

Loading a compiled program still needs the program: JAX traces the Python function again in
every process to find it, and for a fit's solver that tracing takes longer than loading. So the
largest programs of a fit (:func:`persistent_jit`) are also written out as serialized StableHLO
(:mod:`jax.export`, a flatbuffer, never a pickle) under ``exported/`` of the same folder, keyed on
the solver's configuration, the argument shapes and dtypes, the JAX version and a hash of
matfit's own source; a later process reads the program back instead of tracing it.

The solvers' programs loop over a whole table; :func:`loop_jit` compiles them with
:data:`LOOP_COMPILER_OPTIONS` (no while-loop-invariant code motion: see its comment), and
:func:`persistent_jit` compiles what it reads back with the same options.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

import numpy as np

__all__ = ["cache_dir", "enable_compilation_cache", "persistent_jit", "LOOP_COMPILER_OPTIONS", "loop_jit"]

#: XLA options of the programs that iterate over a whole table (the solvers). XLA's
#: while-loop-invariant code motion hoists everything in a loop body that depends only on the
#: table (clamped cosines, table indices, ...) out of the loop; the body then reads each of those
#: as an array written once, and on XLA's CPU backend reading a dozen million-entry arrays per
#: iteration costs more than recomputing them inside the loop's fused kernels: an LM iteration
#: on a full MERL table ran about half as fast (figures in ``docs/performance.md``).
LOOP_COMPILER_OPTIONS = {"xla_disable_hlo_passes": "while-loop-invariant-code-motion"}

#: Where :func:`persistent_jit` keeps exported programs; set by :func:`enable_compilation_cache`.
_exported_dir: Path | None = None

#: Programs that compile faster than this (seconds) are not written to the cache.
MIN_COMPILE_SECONDS = 0.05


def cache_dir() -> Path | None:
    """The folder of the persistent compilation cache, or None when ``MATFIT_NO_CACHE`` is set.

    Returns
    -------
    Path or None
        ``$MATFIT_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/matfit/jax`` (default
        ``~/.cache/matfit/jax``); None when ``MATFIT_NO_CACHE`` is set to anything but ``0``.
        The folder is not created.
    """
    if os.environ.get("MATFIT_NO_CACHE", "").strip() not in ("", "0"):
        return None
    explicit = os.environ.get("MATFIT_CACHE_DIR", "").strip()
    if explicit:
        return Path(explicit).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or Path.home() / ".cache"
    return Path(base) / "matfit" / "jax"


def enable_compilation_cache(path=None) -> Path | None:
    """Switch on JAX's persistent compilation cache in ``path`` (default: :func:`cache_dir`).

    Parameters
    ----------
    path : str or Path, optional
        The cache folder; created when missing.

    Returns
    -------
    Path or None
        The folder in use, or None when ``MATFIT_NO_CACHE`` is set or the folder cannot be
        created (JAX's settings are then untouched: the cache is an optimization, matfit works
        without it).
    """
    import jax

    where = Path(path).expanduser() if path is not None else cache_dir()
    if where is None:
        return None
    try:
        where.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(where))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    global _exported_dir
    _exported_dir = where / "exported"
    return where


@functools.lru_cache(maxsize=1)
def _source_hash() -> str:
    """A hash of matfit's own source files: an exported program is only reused by the code that
    wrote it."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def _plain(key) -> bool:
    """True for a key made only of values whose ``repr`` is the same in every process."""
    if key is None or isinstance(key, (bool, int, float, str, np.generic)):
        return True
    if isinstance(key, (tuple, list)):
        return all(_plain(k) for k in key)
    return False


def loop_jit(fun, **kwargs):
    """:func:`jax.jit` with :data:`LOOP_COMPILER_OPTIONS`, for programs whose loops run over a
    whole table.

    Parameters
    ----------
    fun : callable
    **kwargs
        Passed on to :func:`jax.jit`.

    Returns
    -------
    callable
    """
    import jax

    return jax.jit(fun, compiler_options=LOOP_COMPILER_OPTIONS, **kwargs)


class _PersistentJit:
    """The callable of :func:`persistent_jit`."""

    def __init__(self, jitted, key, compiler_options=None):
        import jax

        self.jitted = jitted  # under a transformation (JAX takes compiler options at the top only)
        self.key = key
        self.compiler_options = compiler_options
        self.top = jitted if not compiler_options else jax.jit(jitted.__wrapped__, compiler_options=compiler_options)
        self.loaded = {}  # signature -> jitted call of the exported program
        self.__wrapped__ = jitted

    def __call__(self, *args):
        import jax

        where = _exported_dir
        leaves, tree = jax.tree_util.tree_flatten(args)
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return self.jitted(*args)
        if where is None or not _plain(self.key) or not all(isinstance(x, (jax.Array, np.ndarray)) for x in leaves):
            return self.top(*args)
        sig = (str(tree), tuple((x.shape, str(jax.dtypes.canonicalize_dtype(x.dtype))) for x in leaves))
        call = self.loaded.get(sig)
        if call is None:
            call = self._load_or_export(where, sig, args)
            self.loaded[sig] = call
        return call(*args)

    def _load_or_export(self, where, sig, args):
        import jax
        from jax import export

        text = repr((self.key, sig, jax.__version__, jax.config.jax_enable_x64, jax.default_backend(),
                     jax.device_count(), _source_hash()))
        path = where / (hashlib.sha256(text.encode()).hexdigest()[:32] + ".jaxexport")
        try:
            exp = export.deserialize(bytearray(path.read_bytes()))
        except Exception:  # noqa: BLE001 - missing, truncated or foreign: trace and write it again
            try:
                exp = export.export(self.jitted)(*args)
                blob = exp.serialize()
            except Exception:  # noqa: BLE001 - a program jax.export cannot serialize: plain jit
                return self.top
            try:
                where.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_bytes(blob)
                os.replace(tmp, path)
            except OSError:
                pass
        return jax.jit(exp.call, compiler_options=self.compiler_options)


def persistent_jit(jitted, key, compiler_options=None):
    """``jitted`` (a :func:`jax.jit` function), whose traced program is kept across processes.

    With the compilation cache on (:func:`enable_compilation_cache`) the first call for each
    argument signature writes the traced program (:func:`jax.export.export`) to the cache folder,
    and later processes read it instead of tracing ``jitted`` again; compiled code then comes
    from JAX's persistent cache as before. With the cache off, under a JAX transformation, for
    a ``key`` whose ``repr`` is not the same in every process, or for a program that
    :mod:`jax.export` cannot serialize, it is ``jitted`` itself.

    Parameters
    ----------
    jitted : callable
        A :func:`jax.jit` function of arrays (pytrees of arrays) only, without compiler options
        (JAX refuses them on a jit called inside a transformation).
    key : tuple
        Everything ``jitted``'s program depends on besides its arguments' shapes and dtypes
        (strings, numbers, tuples of them): the configuration it was built for.
    compiler_options : dict, optional
        The XLA options ``jitted`` was compiled with (e.g. :data:`LOOP_COMPILER_OPTIONS`), used
        again to compile the program read back.

    Returns
    -------
    callable

    Examples
    --------
    >>> import jax, jax.numpy as jnp
    >>> from matfit.cache import persistent_jit
    >>> f = persistent_jit(jax.jit(lambda x: 2 * x), ("double", 1))
    >>> f(jnp.arange(3.0)).tolist()
    [0.0, 2.0, 4.0]
    """
    return _PersistentJit(jitted, key, compiler_options)
