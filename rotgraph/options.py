"""How an estimator takes its options, the one mechanism for all of them: an options object
(a frozen dataclass derived from :class:`Options`: :class:`~rotgraph.SolveOptions`,
:class:`~rotgraph.MeanOptions`, :class:`~rotgraph.HandEyeOptions`,
:class:`~rotgraph.CertifyOptions`, :class:`~rotgraph.RefineOptions`,
:class:`~rotgraph.ProblemOptions`) and keyword overrides of its fields, as in
``average_rotations(graph, options, **overrides)``: :func:`resolve_options`. The positional
arguments of an earlier version of a function still work, as keyword overrides with a
``DeprecationWarning``: :func:`legacy_positional`. Without numpy, as :mod:`rotgraph.choices`.
"""

from __future__ import annotations

import warnings
from dataclasses import fields, replace
from typing import Callable, Collection, Mapping, Sequence, TypeVar

from .errors import OptionError, UnknownOptionError

__all__ = ["Options", "resolve_options", "legacy_positional", "check_choice", "check_fields"]

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


def legacy_positional(form: str, values: tuple, names: Sequence[str], overrides: dict, instead: str, *,
                      leading: int = 0, taken: Collection[str] = (), stacklevel: int = 3) -> None:
    """The positional arguments of an earlier version of a function, still taken: ``values``
    (its arguments ``names``, in that order) moved into ``overrides`` (the call's keyword
    overrides of its options, :func:`resolve_options`) with a ``DeprecationWarning``
    ``"{form} is deprecated: {instead}"`` (e.g. ``form`` ``"mean(rotations, metric, norm,
    weights)"``), warned at the function's caller.

    Parameters
    ----------
    form : str
        The earlier call form, ``"name(arguments)"``; ``name`` is the function's.
    values : tuple
        The positional values of the call (after the ``leading`` data arguments).
    names : sequence of str
        The earlier version's names of those positions.
    overrides : dict
        The call's keyword overrides; the values are added to it, in place.
    instead : str
        What to write now (the warning's second half).
    leading : int, default 0
        The positional arguments before ``values`` (the data), for the counts in messages.
    taken : collection of str, default ()
        Names the call also gave by a keyword of the function's own (not in ``overrides``).
    stacklevel : int, default 3
        ``warnings.warn``'s: 3 when the function itself calls this.

    Raises
    ------
    TypeError
        More values than ``names``, or a value also given by keyword, as Python would.
    """
    function = form.partition("(")[0]
    if len(values) > len(names):
        raise TypeError(f"{function}() takes at most {leading + len(names)} positional arguments but "
                        f"{leading + len(values)} were given")
    warnings.warn(f"{form} is deprecated: {instead}", DeprecationWarning, stacklevel=stacklevel)
    for name, value in zip(names, values):
        if name in overrides or name in taken:
            raise TypeError(f"{function}() got multiple values for argument {name!r}")
        overrides[name] = value
