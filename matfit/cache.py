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
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir", "enable_compilation_cache"]

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

    Examples
    --------
    >>> import os
    >>> from matfit.cache import cache_dir
    >>> saved = os.environ.pop("MATFIT_NO_CACHE", None)
    >>> os.environ["MATFIT_CACHE_DIR"] = "/tmp/matfit-doc-cache"
    >>> str(cache_dir())
    '/tmp/matfit-doc-cache'
    >>> del os.environ["MATFIT_CACHE_DIR"]
    >>> if saved is not None: os.environ["MATFIT_NO_CACHE"] = saved
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
        created (the cache is an optimization: matfit works without it).

    Examples
    --------
    >>> import os
    >>> from matfit.cache import enable_compilation_cache
    >>> os.environ["MATFIT_NO_CACHE"] = "1"
    >>> enable_compilation_cache() is None  # turned off: JAX's settings untouched
    True
    >>> del os.environ["MATFIT_NO_CACHE"]
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
    return where
