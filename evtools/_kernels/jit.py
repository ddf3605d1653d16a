"""Kernels compiled by numba, loaded without numba: every process starts 0.2-0.3 s sooner.

Importing numba (0.15-0.21 s) and the first call of a kernel from numba's cache (0.12 s, numba filling its typing and
lowering registries) cost a process more than filtering 10M events takes. So a kernel here is compiled by numba
once, as a C-callable wrapper (``numba.cfunc``) for the argument types it was called with, and its machine code
is stored as an object file (``store.cache_dir``) and, where the system has a C compiler, linked into a shared
library (``store._link``); later processes load that library with ctypes alone (or, without one, the object with
llvmlite: numba's own code generator, 45 MiB and 50 ms more per process) and call it through ctypes, which releases
the GIL as ``nogil`` did. numba is imported only when an object is missing or stale, or for a call the wrapper
cannot express (``store._describe``); either way the result is numba's, bit for bit (the wrapper calls the same
compiled kernel).

- ``@kernel`` replaces ``@njit(cache=True, nogil=True)`` (``@kernel(inline=True)``: numba's ``inline="always"``,
  the helper's body compiled into its callers); numba's cache is stamped with every kernel source, as the store is
  (:func:`_kernels_cache`); kernel modules never import numba at module level.
- ``deferred(build)`` holds a numba extension (an intrinsic, an overload) made by ``build()`` when numba is first
  imported: :func:`numba_module` builds every one of them before anything is compiled.

A kernel must not raise (its processor validates the parameters, divisors included): inside the C wrapper numba
can only print an exception, not pass it on. An object is reused only under the same key: the kernels' sources, the
argument types, numba's and llvmlite's installed files, the Python version, the host CPU and every ``NUMBA_*``
setting (``store._environment``, ``store._sources``). Its undefined symbols are checked before it is loaded (a missing
one would abort the process inside LLVM), else numba runs it.

This module is what a kernel author uses (``@kernel``, ``deferred``, ``numba_module``); the store itself, which
they never need to read, is :mod:`evtools._kernels.store`, imported on a kernel's first call.
"""

from __future__ import annotations

import os
import sys
import threading

KERNEL_MODES = ("store", "numba")
"""``EVTOOLS_KERNELS``: ``store`` (the default: stored machine code called through ctypes, this module) or ``numba``
(numba's own dispatchers and on-disk cache, ``@njit(cache=True, nogil=True)`` as DESIGN.md writes them): the fence
around the store, for a numba it does not know yet or a doubt about its results (CI runs the suite both ways)."""
MODE = os.environ.get("EVTOOLS_KERNELS", "store").strip().lower() or "store"
if MODE not in KERNEL_MODES:
    raise ValueError(f"EVTOOLS_KERNELS={MODE!r}: choose {' (the default) or '.join(KERNEL_MODES)}")

_LOCK = threading.RLock()
_DEFERRED: list["Deferred"] = []
_NUMBA = None  # the numba module, once imported by numba_module()
_STORE = None  # evtools._kernels.store, once a kernel is called


def _store_module():
    """The machine-code store (imported on the first call of a kernel: it imports numpy and ctypes)."""
    global _STORE
    if _STORE is None:
        from evtools._kernels import store

        _STORE = store
    return _STORE


class Deferred:
    """A numba object (intrinsic, overload registration) built by ``build()`` once numba is imported."""

    def __init__(self, build):
        self.build_function = build
        self.value = None

    def build(self):
        if self.value is None:
            self.value = self.build_function()
        return self.value


def deferred(build):
    """``build()`` now when numba is imported, else a :class:`Deferred` that :func:`numba_module` builds."""
    if _NUMBA is not None:
        return build()
    item = Deferred(build)
    _DEFERRED.append(item)
    return item


class Kernel:
    """A numba kernel called from Python through its stored machine code (see the module docstring); inside other
    kernels it is numba's own dispatcher (:func:`numba_module` registers its type)."""

    def __init__(self, function, inline: bool):
        self.py_func = function
        self.inline = inline
        self.__name__ = function.__name__
        self.__qualname__ = function.__qualname__
        self.__doc__ = function.__doc__
        self.__module__ = function.__module__
        self.__wrapped__ = function
        self._dispatcher = None
        self._calls: dict[tuple, object] = {}

    @property
    def targetoptions(self) -> dict:
        """The options numba's inlining pass reads from a callee (as from its own dispatchers): without them an
        ``inline=True`` kernel called from another kernel was compiled as a separate function and called."""
        return {"inline": "always"} if self.inline else {}

    @property
    def dispatcher(self):
        """numba's dispatcher of this kernel (imports numba)."""
        if self._dispatcher is None:  # no lock: numba may ask for it while compiling (under its own lock), and
            # two threads making it at once make equal dispatchers
            options = {"nogil": True}
            if self.inline:
                options["inline"] = "always"
            dispatcher = numba_module().njit(**options)(self.py_func)
            try:  # numba's enable_caching(), with the stamp of every source
                dispatcher._cache = _kernels_cache(self)
            except RuntimeError:  # no writable place for a cache: compiled in every process (numba's own
                pass  # cache=True would refuse the kernel)
            self._dispatcher = dispatcher
        return self._dispatcher

    def __call__(self, *args):
        if MODE == "numba":
            return self.dispatcher(*args)
        store = _store_module()
        kinds = tuple(map(store._describe, args))
        call = self._calls.get(kinds)
        if call is None:
            with _LOCK:
                call = self._calls.get(kinds)
                if call is None:
                    call = self._calls[kinds] = store._NativeCall.get(self, args, kinds) if None not in kinds else False
        if call is False:
            return self.dispatcher(*args)
        return call(args)

    def __repr__(self) -> str:
        return f"<evtools kernel {self.__module__}.{self.__qualname__}>"


def kernel(function=None, *, inline: bool = False):
    """Decorator: ``@kernel`` or ``@kernel(inline=True)`` (see the module docstring)."""
    if function is None:
        return lambda f: Kernel(f, inline)
    return Kernel(function, inline)


# ---- numba, only when needed ----


def numba_module():
    """Import numba, teach it :class:`Kernel` (typed as its dispatcher) and build every :class:`deferred`."""
    global _NUMBA
    if _NUMBA is not None:
        return _NUMBA
    with _LOCK:
        if _NUMBA is None:
            import numba
            from numba.extending import typeof_impl

            typeof_impl.register(Kernel)(lambda value, context: numba.types.Dispatcher(value.dispatcher))
            for item in _DEFERRED:
                item.build()
            for module in list(sys.modules.values()):  # kernel modules refer to deferred objects by name
                if getattr(module, "__name__", "").startswith("evtools._kernels"):
                    for name, value in list(vars(module).items()):
                        if isinstance(value, Deferred):
                            setattr(module, name, value.build())
            _NUMBA = numba
    return _NUMBA


def _kernels_cache(kernel: Kernel):
    """numba's on-disk cache of ``kernel`` (``cache=True``), stamped with the digest of every kernel source
    (``store._sources``) instead of the kernel's own file alone: a kernel inlines helpers and reads constants of other
    kernel modules (``mlpf`` inlines ``bafilter``'s), and numba's own stamp would keep their old code after they
    change (then stored in the object store too, whose key does cover every source)."""
    from numba.core import caching

    class Stamped:
        def get_source_stamp(self):
            return _store_module()._sources(kernel)

    class UserProvided(Stamped, caching.UserProvidedCacheLocator):  # NUMBA_CACHE_DIR, when set
        pass

    class InUserCache(Stamped, caching.UserProvidedCacheLocator):  # else evtools' folder of the user's cache
        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            self._cache_path = os.path.join(_store_module().user_cache() / "numba",
                                            self.get_suitable_cache_subpath(py_file))

        @classmethod
        def from_function(cls, py_func, py_file):
            if not os.path.exists(py_file):
                return None
            locator = cls(py_func, py_file)
            try:
                locator.ensure_cache_path()
            except OSError:
                return None
            return locator

    class Impl(caching.CompileResultCacheImpl):
        _locator_classes = [UserProvided, InUserCache]  # never inside the package (a cache left there by an
        # uninstalled version broke the next editable install)

    class Cache(caching.FunctionCache):
        _impl_class = Impl

    return Cache(kernel.py_func)
