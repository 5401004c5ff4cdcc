"""How an estimator takes its options, the one mechanism for all of them: an options object
(a frozen dataclass derived from :class:`Options`: :class:`~rotgraph.SolveOptions`,
:class:`~rotgraph.MeanOptions`, :class:`~rotgraph.HandEyeOptions`,
:class:`~rotgraph.CertifyOptions`) and keyword overrides of its fields, as in
``average_rotations(graph, options, **overrides)``: :func:`resolve_options`. Without numpy,
as :mod:`rotgraph.choices`.
"""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Callable, Collection, Mapping, TypeVar

from .errors import OptionError, UnknownOptionError

__all__ = ["Options", "resolve_options", "check_choice", "check_fields"]

T = TypeVar("T", bound="Options")


class Options:
    """Base of rotgraph's options classes, frozen dataclasses whose fields have their unit
    in their name (``_deg``, ``_rad``); a subclass says in :meth:`check` what a bad value is.
    """

    def validated(self: T) -> T:
        """These options, checked (each estimator calls this on the options it is given).

        Returns
        -------
        Options
            ``self``, unchanged.

        Raises
        ------
        OptionError
            A field with a bad value, named in the one-line message (also a ``ValueError``);
            :meth:`check` of the class says which values are bad.
        """
        self.check()
        return self

    def check(self) -> None:
        """Raise :class:`~rotgraph.errors.OptionError` for a field with a bad value."""
        raise NotImplementedError


def check_choice(field: str, value, choices: Collection[str]) -> None:
    """:class:`~rotgraph.errors.OptionError` unless ``value`` is one of ``choices`` (the
    values field ``field`` accepts)."""
    if value not in choices:
        raise OptionError(f"unknown {field} {value!r}; expected one of {', '.join(choices)}")


def check_fields(options: Options, names: Collection[str], test: Callable[[object], bool], what: str) -> None:
    """:class:`~rotgraph.errors.OptionError` naming the first of the fields ``names`` of
    ``options`` whose value fails ``test`` (e.g. ``lambda v: v > 0``; ``what``, e.g.
    ``"> 0"``, says what it should be). None passes where it is the field's default."""
    defaults = {f.name: f.default for f in fields(options)}
    for name in names:
        value = getattr(options, name)
        if value is None and defaults[name] is None:
            continue
        try:
            ok = value is not None and bool(test(value))
        except TypeError:  # e.g. a string where a number belongs
            ok = False
        if not ok:
            raise OptionError(f"{name} must be {what}, got {value!r}")


def resolve_options(cls: type[T], options: T | None, overrides: Mapping[str, object]) -> T:
    """The options of one call: ``options`` (default ``cls()``) with the fields named in
    ``overrides`` replaced, validated.

    Parameters
    ----------
    cls : type
        The options dataclass, a subclass of :class:`Options`.
    options : cls or None
        The caller's options object; None: ``cls()``, the defaults.
    overrides : mapping of str to object
        Field name to value, the call's keyword arguments beyond its data.

    Returns
    -------
    cls
        The validated options (``options`` itself when nothing is overridden).

    Raises
    ------
    OptionError
        ``options`` not a ``cls``, or a bad value (from ``cls.validated``).
    UnknownOptionError
        A keyword that is no field of ``cls`` (an ``OptionError`` and a ``TypeError``, as
        Python's own unexpected keyword argument).
    """
    if options is None:
        options = cls()
    elif not isinstance(options, cls):
        raise OptionError(f"options must be a {cls.__name__}, got {type(options).__name__}")
    names = [f.name for f in fields(cls)]
    unknown = [k for k in overrides if k not in names]
    if unknown:
        raise UnknownOptionError(f"unknown option {unknown[0]!r}; {cls.__name__} has {', '.join(names)}")
    return (replace(options, **overrides) if overrides else options).validated()
