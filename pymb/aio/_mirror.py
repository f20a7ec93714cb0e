"""Async methods made from blocking ones, so the two cannot drift apart.

``read_all = Mirror(SensorHub.read_all)`` in an async class gives it a
coroutine method ``read_all`` with the blocking method's name, signature,
docstring and type (for mypy too: its arguments and its result are the
blocking method's), which runs that method of the object's ``blocking``
twin on the line's worker thread. ``port = Forward[str]("...")`` gives it a
read-only property that reads the twin's attribute of that name (no I/O).
"""

from __future__ import annotations

import abc
import inspect
import typing
from collections.abc import Awaitable, Callable, Coroutine
from types import FunctionType, MethodType
from typing import TYPE_CHECKING, Any, Concatenate, Generic, ParamSpec, TypeVar, overload

__all__ = ["Forward", "Mirror", "Mirrored"]

P = ParamSpec("P")
R = TypeVar("R")
S = TypeVar("S")
T = TypeVar("T")


class Mirrored(abc.ABC):
    """What a class with :class:`Mirror` methods has: the blocking twin
    and a way to run one of its calls on the line's worker."""

    blocking: object  #: the blocking twin, whose methods the mirrors run

    @abc.abstractmethod
    def _submit(self, fn: Callable[P, R], /, *args: P.args,
                **kwargs: P.kwargs) -> Awaitable[R]:
        """Run ``fn(*args, **kwargs)``, a request, on the line's worker."""

    def _submit_setting(self, fn: Callable[P, R], /, *args: P.args,
                        **kwargs: P.kwargs) -> Awaitable[R]:
        """Run ``fn(*args, **kwargs)``, a setting, on the line's worker (a
        close() does not drop it)."""
        return self._submit(fn, *args, **kwargs)


def _coroutine(name: str, setting: bool) -> FunctionType:
    if setting:
        async def method(self: Mirrored, /, *args: object, **kwargs: object) -> object:
            return await self._submit_setting(getattr(self.blocking, name), *args, **kwargs)
    else:
        async def method(self: Mirrored, /, *args: object, **kwargs: object) -> object:
            return await self._submit(getattr(self.blocking, name), *args, **kwargs)
    assert isinstance(method, FunctionType)  # an async def is a function object
    return method


class Mirror(Generic[S, P, R]):
    """A blocking method (``Class.method``, of a class ``S``) as a coroutine
    method of the same name that runs it on the line's worker; ``setting``:
    it changes a setting and uses no line (a close() leaves it queued)."""

    def __init__(self, method: Callable[Concatenate[S, P], R], *, setting: bool = False) -> None:
        self.method = method
        self.name: str = method.__name__
        fn = _coroutine(self.name, setting)
        fn.__name__ = self.name
        fn.__doc__ = method.__doc__
        fn.__dict__["__signature__"] = inspect.signature(method)
        self.fn = fn

    def __set_name__(self, owner: type, name: str) -> None:
        if name != self.name:
            raise TypeError(f"{owner.__name__}.{name} mirrors a method named {self.name}")
        self.fn.__qualname__ = f"{owner.__qualname__}.{name}"
        self.fn.__module__ = owner.__module__

    @overload
    def __get__(self, obj: None, owner: type | None = None
                ) -> Callable[Concatenate[Mirrored, P], Coroutine[object, None, R]]: ...

    @overload
    def __get__(self, obj: object, owner: type | None = None
                ) -> Callable[P, Coroutine[object, None, R]]: ...

    def __get__(self, obj: object | None, owner: type | None = None
                ) -> Callable[..., Coroutine[object, None, R]]:
        if obj is None:
            return self.fn
        return MethodType(self.fn, obj)


class Forward(property, Generic[T]):
    """A read-only property (a :class:`property`, ``doc`` its docstring) that
    reads the ``blocking`` twin's attribute of the same name, at once: no
    I/O, no turn on the worker. Its getter is named and typed as a written
    one would be (``Forward[int]``: ``(self) -> int``), and a read is
    :class:`property`'s own."""

    def __init__(self, doc: str) -> None:
        def get(self: Any) -> Any:  # (self: the async object; named in __set_name__)
            return getattr(self.blocking, get.__name__)
        get.__doc__ = doc
        super().__init__(get, doc=doc)
        self.__doc__ = doc  # a property subclass's own docstring would stand instead
        self._get = get

    def __set_name__(self, owner: type, name: str) -> None:
        get = self._get
        get.__name__, get.__qualname__ = name, f"{owner.__qualname__}.{name}"
        get.__module__ = owner.__module__
        # Forward[T](...) has set __orig_class__ by now: T is the getter's result
        given = typing.get_args(getattr(self, "__orig_class__", None))
        get.__annotations__ = {"return": given[0]} if given else {}
        super().__set_name__(owner, name)  # type: ignore[misc]  # (the setter error names it)

    if TYPE_CHECKING:  # the types mypy sees; a read runs property.__get__ itself
        @overload
        def __get__(self, obj: None, owner: type | None = None) -> Forward[T]: ...

        @overload
        def __get__(self, obj: object, owner: type | None = None) -> T: ...

        def __get__(self, obj: object | None, owner: type | None = None) -> Any: ...
