"""How the package compiles a function with numba: the two decorators every kernel uses.

Both cache the machine code on disk (see warmup.py). What they leave out is what the package never calls, and
each costs compile time on a first run (docs/startup.md has the measurements):

* ``kernel``: a function called from Python. numba would also build a C-callable (cfunc) wrapper for it,
  which nothing here uses.
* ``stage``: a function called only from other compiled functions (a stage of a kernel, a scalar formula).
  Its code is linked into each caller, so it needs no Python wrapper either: boxing and unboxing every
  argument is a large share of a small function's code.

Neither changes the arithmetic: the same machine code runs, to the last bit.
"""
from numba import njit

kernel = njit(cache=True, no_cfunc_wrapper=True)
stage = njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)


# ----------------------------------------------------------------------------------------------- calls by address
# A compiled function that calls a kernel directly links the kernel's code into its own and has LLVM optimise
# and generate all of it again (a caller of the bend-twist kernel alone compiled ~1.3 s). Calling it by address
# instead, through numba's first-class function type with the kernel's own (native) calling convention, costs
# the caller nothing of the kernel's compile and keeps one machine code of every kernel in the process; the
# address is an argument (an int64) of the caller, so the caller's cached code holds no address.
_SPEC = None


def signature(spec: str):
    """A numba signature from a compact spec, "RET ARG ARG ...": f1 f2 f3 / i1 i2 i3 / n1 C-contiguous float64 /
    int64 / int32 arrays of that many dimensions, f i b float64 int64 boolean scalars, - none, and "( ... )" a
    tuple of those (the type numba gives a Python tuple of such values)."""
    global _SPEC
    from numba import types as t
    if _SPEC is None:
        _SPEC = {"f1": t.float64[::1], "f2": t.float64[:, ::1], "f3": t.float64[:, :, ::1], "i1": t.int64[::1],
                 "i2": t.int64[:, ::1], "i3": t.int64[:, :, ::1], "n1": t.int32[::1], "f": t.float64,
                 "i": t.int64, "b": t.boolean, "-": t.none}
    stack = [[]]
    for tok in spec.replace("(", " ( ").replace(")", " ) ").split():
        if tok == "(":
            stack.append([])
        elif tok == ")":
            members = stack.pop()
            stack[-1].append(t.Tuple(members))
        else:
            stack[-1].append(_SPEC[tok])
    ret, *args = stack[0]
    return ret(*args)


def function_at(spec: str):
    """A compiled helper ``f = at(address)`` that turns an int64 address of a kernel compiled for the signature
    ``spec`` (see :func:`signature`) into a callable with that signature (exceptions propagate as from a direct
    call). The address comes from :func:`address`."""
    from numba import types
    from numba.core import cgutils
    from numba.core.extending import intrinsic
    fnty = types.FunctionType(signature(spec))

    @intrinsic
    def at(typingctx, addr):
        def codegen(context, builder, sig, args):
            f = cgutils.create_struct_proxy(fnty)(context, builder)
            f.jit_addr = builder.inttoptr(args[0], cgutils.voidptr_t)
            return f._getvalue()
        return fnty(types.int64), codegen
    return at


def address(dispatcher, spec: str) -> int:
    """The address of ``dispatcher``'s machine code for the signature ``spec`` (compiled or loaded first if this
    process has not yet)."""
    from numba.experimental.function_type import _get_jit_address
    return int(_get_jit_address(dispatcher, signature(spec)))


# ----------------------------------------------------------------------------------------------- interpreted twins
_TWINS: dict = {}


def interpreted(dispatcher):
    """The plain-Python twin of a compiled function: its own source code run by the interpreter, with every
    compiled function it calls replaced by that function's twin (so calling it compiles nothing).

    The arithmetic is the same operation for operation (IEEE double in both; numba contracts nothing into fused
    multiply-adds and calls the C library's ``sqrt``, ``sin``, ``atan2`` as ``math`` does), so it gives the same
    numbers to the last bit, only slower: what a first run uses while a background process compiles the kernel
    (warmup.py). A C function it calls by symbol (``types.ExternalFunction``: LAPACK, linsolve.py) is called
    through ctypes (:func:`external`), the very same function. Memoised: one twin per function."""
    from numba.core.dispatcher import Dispatcher
    from numba.core.types import ExternalFunction
    twin = _TWINS.get(dispatcher)
    if twin is None:
        import types as pytypes
        f = dispatcher.py_func
        ns = dict(f.__globals__)
        twin = _TWINS[dispatcher] = pytypes.FunctionType(f.__code__, ns, f.__name__, f.__defaults__, f.__closure__)
        for name in _global_names(f.__code__):
            value = ns.get(name)
            if isinstance(value, Dispatcher):
                ns[name] = interpreted(value)
            elif isinstance(value, ExternalFunction):
                ns[name] = external(value)
    return twin


def external(fn):
    """A C function that compiled code calls by symbol (``types.ExternalFunction``, registered with LLVM), callable
    from Python through ctypes: int64, int32 and float64 arguments, those or no result. Memoised."""
    twin = _TWINS.get(fn)
    if twin is None:
        import ctypes

        import llvmlite.binding as llvm
        from numba import types
        c = {types.int64: ctypes.c_int64, types.int32: ctypes.c_int32, types.float64: ctypes.c_double,
             types.none: None}
        twin = _TWINS[fn] = ctypes.CFUNCTYPE(c[fn.sig.return_type], *(c[a] for a in fn.sig.args))(
            llvm.address_of_symbol(fn.symbol))
    return twin


def _global_names(code) -> set[str]:
    """The names a code object (and the code nested in it) may look up among its globals."""
    names = set(code.co_names)
    for c in code.co_consts:
        if hasattr(c, "co_names"):
            names |= _global_names(c)
    return names
