"""The machine-code store behind :mod:`evtools._kernels.jit` (its module docstring says why): the argument
descriptions a stored kernel is keyed and called by, the user-cache folders, the keys (sources, environment, host
CPU), numba's compilation of a C-callable wrapper, loading it with llvmlite or linking it into a shared library, and
the ctypes call. A kernel author needs none of it: ``@kernel`` (jit.py) is the whole interface; this module is
imported on a kernel's first call, never under ``EVTOOLS_KERNELS=numba``.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import hashlib
import importlib.machinery
import importlib.util
import os
import pickle
import sys
from pathlib import Path

import numpy as np

from evtools._kernels.jit import Kernel, numba_module

# ---- argument descriptions ----

_SCALAR_CTYPES = {"?": ctypes.c_bool, "b1": ctypes.c_bool, "i1": ctypes.c_int8, "u1": ctypes.c_uint8,
                  "i2": ctypes.c_int16, "u2": ctypes.c_uint16, "i4": ctypes.c_int32, "u4": ctypes.c_uint32,
                  "i8": ctypes.c_int64, "u8": ctypes.c_uint64, "f4": ctypes.c_float, "f8": ctypes.c_double}


_RECORD_CODES: dict = {}


_ARRAY_KINDS: dict = {}


def _describe(value):
    """What the C wrapper must know of one argument, or None when it cannot pass it (numba's dispatcher then
    runs the call): arrays of numbers or of records that are C-contiguous, or 1-D with a positive stride that is a
    whole number of items (a field of an event array); bools, ints (int64, as numba types them), floats, numpy
    scalars. An array's kind is looked up by its dtype, dimensions, flags and stride (1.2 -> 0.4 us: every call
    describes every argument, and a stream of small chunks makes many calls)."""
    if type(value) is np.ndarray:
        flags = value.flags
        contiguous = flags.c_contiguous
        key = (value.dtype, value.ndim, contiguous, flags.writeable, 0 if contiguous else value.strides[0])
        kind = _ARRAY_KINDS.get(key, _describe)  # (_describe: not described yet)
        if kind is _describe:
            kind = _ARRAY_KINDS[key] = _describe_array(value)
        return kind
    if isinstance(value, np.ndarray):
        return _describe_array(value)
    if isinstance(value, (bool, np.bool_)):
        return ("scalar", "b1")
    if isinstance(value, int):
        return ("scalar", "i8") if -(1 << 63) <= value < (1 << 63) else None
    if isinstance(value, float):
        return ("scalar", "f8")
    if isinstance(value, np.generic):
        code = value.dtype.str[1:]
        return ("scalar", code) if code in _SCALAR_CTYPES else None
    return None


def _describe_array(value: np.ndarray):
    """:func:`_describe` of an array: ("array", type code, dimensions, writeable, step in items), or None."""
    dtype = value.dtype
    if dtype.names is not None:  # a structured array (a pixel state table): its layout is part of the key
        code = _RECORD_CODES.get(dtype)
        if code is None:  # repr of a record type takes 20 us: made once per type (its hash is cached)
            code = _RECORD_CODES[dtype] = repr(dtype) if not dtype.hasobject else None
    else:
        code = dtype.str[1:] if dtype.str[1:] in _SCALAR_CTYPES and dtype.byteorder in "=|<" else None
    if code is None or value.ndim == 0:
        return None
    step = 1
    if not value.flags.c_contiguous:
        stride = value.strides[0]
        if value.ndim != 1 or stride <= 0 or stride % value.itemsize:
            return None
        step = stride // value.itemsize
    return ("array", code, value.ndim, value.flags.writeable, step)


# ---- the stored machine code ----

def user_cache() -> Path:
    """evtools' folder of the user's cache, ``$XDG_CACHE_HOME/evtools`` (``~/.cache/evtools``): the kernel store
    and numba's cache live there, never inside the installed package."""
    home = Path(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"))  # no error without a home
    return home / "evtools"


def cache_dir() -> Path | None:
    """Where objects are stored: ``native`` in :func:`user_cache`; None when it cannot be written (kernels are then
    compiled in every process)."""
    directory = user_cache() / "native"
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return directory if os.access(directory, os.W_OK) else None


_ENVIRONMENT = None


def _environment() -> str:
    """What every stored object depends on (computed once per process): the installed numba and llvmlite, the
    Python version, the host CPU and the ``NUMBA_*`` settings. Objects of different environments live side by side
    (one folder each), so machines sharing an installation do not evict each other's."""
    global _ENVIRONMENT
    if _ENVIRONMENT is None:
        digest = hashlib.sha256()
        for package in ("numba", "llvmlite"):
            root = importlib.util.find_spec(package).submodule_search_locations[0]
            for path in sorted(glob.glob(os.path.join(root, "*.py")) + glob.glob(os.path.join(root, "*.so"))):
                status = os.stat(path)
                digest.update(f"{path}:{status.st_size}:{status.st_mtime_ns}".encode())
        digest.update(sys.version.encode())
        digest.update(_host_cpu().encode())
        digest.update(repr(sorted((k, v) for k, v in os.environ.items() if k.startswith("NUMBA_"))).encode())
        _ENVIRONMENT = digest.hexdigest()[:16]
    return _ENVIRONMENT


def _host_cpu() -> str:
    """The host CPU's model and features: from ``/proc/cpuinfo`` where there is one (no llvmlite to import), else
    as LLVM names them."""
    try:
        with open("/proc/cpuinfo") as file:
            lines = file.read().split("\n\n")[0].splitlines()
        keys = ("model name", "flags", "cpu family", "model", "stepping", "CPU implementer", "CPU part", "Features")
        identity = [line for line in lines if line.split(":")[0].strip() in keys]
        if identity:
            return "\n".join(identity)
    except OSError:
        pass
    import llvmlite.binding as ll

    return ll.get_host_cpu_name() + ll.get_host_cpu_features().flatten()


_SOURCES = None


def _sources(kernel: Kernel) -> str:
    """Digest of the kernels' sources (every module of ``evtools/_kernels``, as kernels call across modules), and
    of the kernel's own module when it is defined elsewhere (tests)."""
    global _SOURCES
    if _SOURCES is None:
        digest = hashlib.sha256()
        for path in sorted(Path(__file__).parent.glob("*.py")):
            digest.update(path.name.encode() + path.read_bytes())
        _SOURCES = digest.digest()
    digest = hashlib.sha256(_SOURCES)
    if not kernel.__module__.startswith("evtools._kernels."):
        digest.update(Path(sys.modules[kernel.__module__].__file__).read_bytes())
    return digest.hexdigest()[:16]


def _store(record: dict, directory: Path, name: str, stale: str) -> None:
    """Write ``record`` as ``directory/name`` (atomically: under a temporary name, then renamed) and remove the
    files matching ``stale`` but its own shared library (the same kernel and kinds from older sources). A store
    that cannot be written (read-only, full) only costs the next process a compile."""
    import tempfile  # (only where something is stored: 6 ms of every process's start-up otherwise)

    try:
        directory.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=directory, suffix=".tmp")
        with os.fdopen(handle, "wb") as file:
            pickle.dump(record, file)
        os.replace(temporary, directory / name)
        for path in directory.glob(stale):
            if path.stem != Path(name).stem:
                path.unlink(missing_ok=True)
    except OSError:
        pass


def _stored_record(directory: Path | None, name: str) -> dict | None:
    """The store's record ``directory/name``, or None (none there, or damaged: it is rebuilt)."""
    if directory is None or not (directory / name).exists():
        return None
    try:
        return pickle.loads((directory / name).read_bytes())
    except Exception:
        return None


@contextlib.contextmanager
def _compiling(directory: Path | None, lock_name: str):
    """While one process compiles a kernel for the store, others that need the same one wait for it and then load
    it (an advisory lock on ``directory/lock_name``): four `correct` started at once on a fresh install each compiled
    every kernel, 1 min 47 s on 2 cores (a QA sweep). A store that cannot hold the lock file is not waited for."""
    import fcntl

    try:
        directory.mkdir(parents=True, exist_ok=True)
        lock = open(directory / lock_name, "a+b")
    except (OSError, AttributeError):  # (no store, a read-only one)
        yield
        return
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


_ENGINE = None
_KEEP = []  # compiled wrappers and loaded libraries whose code is called
_HELPERS = None


def _helpers() -> dict[str, int]:
    """The addresses of the C helpers numba's code calls, taken from numba's extension modules without importing
    numba itself, under the names numba's code calls them by (``numba_*`` helpers, ``NRT_*`` runtime)."""
    global _HELPERS
    if _HELPERS is None:
        root = importlib.util.find_spec("numba").submodule_search_locations[0]

        def extension(name):
            if name in sys.modules:
                return sys.modules[name]
            stem = os.path.join(root, *name.split(".")[1:])
            path = next(stem + suffix for suffix in importlib.machinery.EXTENSION_SUFFIXES
                        if os.path.exists(stem + suffix))
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            return module

        helpers = {}
        for name in ("numba._helperlib", "numba._dynfunc"):
            helpers.update(("numba_" + helper, address) for helper, address in extension(name).c_helpers.items())
        for helper, address in extension("numba.core.runtime._nrt_python").c_helpers.items():
            helpers[helper if helper.startswith("_") else "NRT_" + helper] = address
        _HELPERS = helpers
    return _HELPERS


def _engine():
    """llvmlite's JIT (MCJIT) with numba's C helpers (:func:`_helpers`), Python's None and exceptions."""
    global _ENGINE
    if _ENGINE is None:
        import builtins

        import llvmlite.binding as ll

        for name, address in _helpers().items():
            ll.add_symbol(name, address)
        ll.add_symbol("_Py_NoneStruct", id(None))
        for value in vars(builtins).values():
            if isinstance(value, type) and issubclass(value, BaseException):
                ll.add_symbol(f"PyExc_{value.__name__}", id(value))
        ll.initialize_native_target()
        ll.initialize_native_asmprinter()
        machine = ll.Target.from_default_triple().create_target_machine()
        _ENGINE = ll.create_mcjit_compiler(ll.parse_assembly(""), machine)
    return _ENGINE


def _load(record: dict) -> int | None:
    """The address of the stored wrapper loaded by llvmlite, or None when one of its symbols cannot be resolved
    here."""
    import llvmlite.binding as ll

    engine = _engine()
    if any(not ll.address_of_symbol(name) for name in record["undefined"]):
        return None
    engine.add_object_file(ll.ObjectFileRef.from_data(record["object"]))
    engine.finalize_object()
    return engine.get_function_address(record["name"]) or None


# ---- the stored machine code as a shared library (no llvmlite: 45 MiB and 50 ms less per process) ----

_TRAMPOLINES = {  # a jump through slot i of the library's table (.Lslots), per machine
    "x86_64": "    jmp *.Lslots+{offset}(%rip)\n",
    "aarch64": "    adrp x16, .Lslots+{offset}\n    ldr x16, [x16, #:lo12:.Lslots+{offset}]\n    br x16\n",
}


def _link(record: dict, path: Path) -> bool:
    """Link the record's object into the shared library ``path`` with the system's C compiler (``$CC``, else
    ``cc``): numba's helpers, hidden inside its extension modules, are reached through trampolines that jump
    through a table the loader fills (``evtools_slots``, in the order of ``record["slots"]``); the other undefined
    symbols (Python's C API, libm) are the process's own. False, and nothing written, where that cannot be done
    (no compiler, another machine, a symbol neither a helper nor the process's)."""
    import platform
    import shutil
    import subprocess
    import tempfile

    compiler = shutil.which(os.environ.get("CC") or "cc") or shutil.which("gcc")
    trampoline = _TRAMPOLINES.get(platform.machine())
    if compiler is None or trampoline is None:
        return False
    process = ctypes.CDLL(None)
    helpers = _helpers()
    slots = [name for name in record["undefined"] if name in helpers]
    if any(name not in helpers and not hasattr(process, name) for name in record["undefined"]):
        return False
    if any(name in record.get("undefined_data", ()) for name in slots):  # a trampoline is code, not data
        return False
    assembly = ["    .text"]
    for i, name in enumerate(slots):
        assembly += [f"    .globl {name}", f"    .hidden {name}", f"    .type {name}, %function", f"{name}:",
                     trampoline.format(offset=8 * i)]
    assembly += ["    .data", "    .p2align 3", "    .globl evtools_slots", "evtools_slots:", ".Lslots:",
                 f"    .zero {8 * max(len(slots), 1)}", '    .section .note.GNU-stack,"",%progbits', ""]
    with tempfile.TemporaryDirectory() as scratch:
        (Path(scratch) / "kernel.o").write_bytes(record["object"])
        (Path(scratch) / "slots.s").write_text("\n".join(assembly))
        linked = Path(scratch) / "kernel.so"
        try:
            done = subprocess.run([compiler, "-shared", "-o", str(linked), "kernel.o", "slots.s", "-lm"],
                                  cwd=scratch, capture_output=True, timeout=120)
        except (OSError, subprocess.SubprocessError):
            return False
        if done.returncode != 0 or not linked.exists():
            return False
        record["slots"] = slots
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            handle, temporary = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
            os.close(handle)
            shutil.copyfile(linked, temporary)
            os.replace(temporary, path)
        except OSError:
            return False
    return True


def _load_library(record: dict, path: Path) -> int | None:
    """The address of the stored wrapper in the shared library ``path`` (see :func:`_link`), its trampolines'
    table filled; None when it cannot be loaded here."""
    slots = record["slots"]
    process = ctypes.CDLL(None)
    if any(name not in slots and not hasattr(process, name) for name in record["undefined"]):
        return None
    try:
        library = ctypes.CDLL(str(path))  # (bound now: a symbol missing here fails the load, not a later call)
        if slots:
            table = (ctypes.c_void_p * len(slots)).in_dll(library, "evtools_slots")
            helpers = _helpers()
            for i, name in enumerate(slots):
                table[i] = helpers[name]
        address = ctypes.cast(getattr(library, record["name"]), ctypes.c_void_p).value
    except (OSError, AttributeError, KeyError, ValueError):
        return None
    _KEEP.append(library)
    return address


def _compile(kernel: Kernel, args: tuple, kinds: tuple) -> dict | None:
    """Compile the C wrapper of ``kernel`` for these arguments with numba: a record of its object code, symbol,
    undefined symbols and result types, or None when its result is not scalars."""
    numba = numba_module()
    types = numba.types
    # type the call as numba would (read-only arrays included): the wrapper only runs what this accepts
    argument_types = tuple(numba.typeof(value) for value in args)
    kernel.dispatcher.compile(argument_types)
    result = kernel.dispatcher.overloads[argument_types].signature.return_type
    results = list(result.types) if isinstance(result, types.BaseTuple) else [] if result == types.none else [result]
    if not all(isinstance(item, (types.Integer, types.Float, types.Boolean)) for item in results):
        return None
    parameters, call, signature = [], [], []
    for i, (kind, numba_type) in enumerate(zip(kinds, argument_types)):
        if kind[0] == "scalar":
            parameters.append(f"a{i}")
            call.append(f"a{i}")
            signature.append(numba_type)
            continue
        _, _, ndim, _, step = kind
        shape = [f"a{i}_{d}" for d in range(ndim)]
        parameters += [f"a{i}"] + shape
        signature += [types.CPointer(numba_type.dtype)] + [types.int64] * ndim
        if step == 1:
            call.append(f"carray(a{i}, ({', '.join(shape)},))")
        else:  # every step-th item of the block that spans the field
            call.append(f"carray(a{i}, (({shape[0]} - 1) * {step} + 1,))[::{step}]")
    outputs = [f"r{i}" for i in range(len(results))]
    lines = [f"def wrapper({', '.join(parameters + outputs)}):", f"    result = kernel({', '.join(call)})"]
    if isinstance(result, types.BaseTuple):
        lines += [f"    r{i}[0] = result[{i}]" for i in range(len(results))]
    elif results:
        lines.append("    r0[0] = result")
    namespace = {"kernel": kernel.dispatcher, "carray": numba.carray}
    exec("\n".join(lines), namespace)
    # a boolean result is stored as a byte (numba stores no i1 through a pointer); ctypes reads it as c_bool
    signature += [types.CPointer(types.uint8 if isinstance(item, types.Boolean) else item) for item in results]
    wrapper = numba.cfunc(types.void(*signature))(namespace["wrapper"])
    library = wrapper._library
    module = library._final_module
    undefined_data = sorted(g.name for g in module.global_variables if g.is_declaration)
    undefined = sorted({f.name for f in module.functions if f.is_declaration and not f.name.startswith("llvm.")}
                       | set(undefined_data))
    return {"name": wrapper.native_name, "object": library._codegen._tm.emit_object(module),
            "undefined": undefined, "undefined_data": undefined_data, "results": [str(item) for item in results],
            "tuple": isinstance(result, types.BaseTuple), "wrapper": wrapper}


_SCALAR, _BUFFER, _ARRAY = range(3)  # how an argument is passed (see _NativeCall.__call__)
_BYTE = ctypes.c_char


class _NativeCall:
    """One kernel for one tuple of argument kinds, called through ctypes."""

    def __init__(self, function, kinds: tuple, results: list[str], is_tuple: bool, origin: str):
        self.function = function
        self.origin = origin  # "store" (loaded) or "compiled" (in this process)
        self.ways = tuple(_SCALAR if kind[0] == "scalar" else _BUFFER if kind[3] and kind[4] == 1 else _ARRAY
                          for kind in kinds)
        self.result_ctypes = [_SCALAR_CTYPES[_numba_code(name)] for name in results]
        self.is_tuple = is_tuple

    @staticmethod
    def get(kernel: Kernel, args: tuple, kinds: tuple):
        """The native call for these kinds (from the store, else compiled and stored), or False for numba's."""
        root = cache_dir()
        directory = root / _environment() if root else None
        kernel_name = f"{kernel.__module__}.{kernel.__qualname__}"
        kinds_digest = hashlib.sha256(repr(kinds).encode()).hexdigest()[:16]
        name = f"{kernel_name}.{_sources(kernel)}.{kinds_digest}.pkl"
        record = _stored_record(directory, name)
        library = directory / (name[:-len(".pkl")] + ".so") if directory is not None else None
        if record is None:
            with _compiling(directory, f".lock-{kernel_name}.{kinds_digest}"):
                record = _stored_record(directory, name)  # (another process may have made it meanwhile)
                if record is None:
                    _say_compiling(kernel_name)
                    record = _compile(kernel, args, kinds)
                    if record is None:
                        return False
                    if directory is not None:
                        if not _link(record, library):
                            library.unlink(missing_ok=True)
                        stored = {key: value for key, value in record.items() if key != "wrapper"}
                        _store(stored, directory, name, f"{kernel_name}.*.{kinds_digest}.[ps][ko]*")
        if "wrapper" in record:  # compiled in this process: numba's JIT already holds it
            _KEEP.append(record["wrapper"])
            address = record["wrapper"].address
        else:
            address = None
            if "slots" in record and library.exists():
                address = _load_library(record, library)
            if address is None:
                try:
                    address = _load(record)
                except Exception:  # whatever keeps the stored code from loading here, numba can still run it
                    address = None
            if address is None:
                return False
        argtypes = []
        for kind in kinds:
            if kind[0] == "scalar":
                argtypes.append(_SCALAR_CTYPES[kind[1]])
            else:  # pointer, then the shape
                argtypes += [ctypes.c_void_p] + [ctypes.c_int64] * kind[2]
        argtypes += [ctypes.c_void_p] * len(record["results"])
        function = ctypes.CFUNCTYPE(None, *argtypes)(address)
        return _NativeCall(function, kinds, record["results"], record["tuple"],
                           "compiled" if "wrapper" in record else "store")

    def __call__(self, args: tuple):
        flat = []
        for way, value in zip(self.ways, args):
            if way == _SCALAR:
                flat.append(value)
            else:  # a writeable contiguous array's address through the buffer protocol: 0.3 us, ctypes.data 1.8
                flat.append(ctypes.addressof(_BYTE.from_buffer(value)) if way == _BUFFER and value.nbytes
                            else value.ctypes.data)
                flat += value.shape
        outputs = [kind() for kind in self.result_ctypes]
        self.function(*flat, *(ctypes.byref(item) for item in outputs))
        values = tuple(item.value for item in outputs)
        if self.is_tuple:
            return values
        return values[0] if values else None


_SAID = []


def _say_compiling(kernel_name: str) -> None:
    """One line on a terminal, once a process, before the first kernel is compiled: the first run of a command (a
    fresh install) compiles its kernels for seconds, and a silent wait looks like a hang."""
    if _SAID or not sys.stderr.isatty():
        return
    _SAID.append(kernel_name)
    sys.stderr.write("evtools: compiling machine code for this machine (the first run of a command only; later runs "
                     "load it)\n")
    sys.stderr.flush()


def _numba_code(name: str) -> str:
    """numpy's type code of numba's scalar type name (``int64`` -> ``i8``, ``bool`` -> ``b1``)."""
    return np.dtype(name).str[1:]
