"""Old names of config fields, kept working: one canonical name per weight (issues 26 and 57).

:func:`renamed_fields` decorates a dataclass config: each old name stays a keyword of the
constructor (mapped onto its canonical field, with a :class:`DeprecationWarning`) and an
attribute (a property reading and writing the canonical field). The old names are not
fields: ``dataclasses.fields``, ``replace`` and the config's ``to_dict`` see the canonical
names only.

:func:`grouped` gives the aliases of fields moved into a group (a small dataclass held by one field, issue 57:
``KeypointFitConfig.image_depth.weight``, once ``image_depth_weight``): each old flat name reads and writes its
group's field, and :func:`flat_dict` records a config with the flat names, as before the move, for the release
the aliases live.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from typing import Callable, NamedTuple, Optional

__all__ = ["Alias", "flat_dict", "flat_names", "flat_value", "grouped", "renamed_fields"]


class Alias(NamedTuple):
    """An old field name's mapping onto canonical field ``field``: ``get(canonical) -> old
    value``; ``put(canonical, old value, keywords) -> canonical`` (``keywords``: the
    constructor's other arguments, e.g. to check a length); both default to a plain rename. ``sub``: the
    group's field where ``field`` holds a group (:func:`grouped`)."""

    field: str
    get: Optional[Callable] = None
    put: Optional[Callable] = None
    sub: Optional[str] = None


def grouped(field: str, **subs: str) -> dict:
    """The aliases of flat names moved into group ``field`` (a dataclass): ``old=sub`` for each."""

    def alias(sub: str) -> Alias:
        return Alias(
            field, lambda group: getattr(group, sub), lambda group, v, kw: dataclasses.replace(group, **{sub: v}), sub
        )

    return {old: alias(sub) for old, sub in subs.items()}


def listed(value):
    """A settings value as JSON keeps it: tuples as lists."""
    return list(value) if isinstance(value, tuple) else value


def flat_names(cls) -> dict:
    """Each group field of ``cls`` (:func:`grouped`) -> its fields' ``(old flat name, field in the group)``."""
    subs: dict = {}
    for old, a in getattr(cls, "renamed_fields", {}).items():
        if a.sub is not None:
            subs.setdefault(a.field, []).append((old, a.sub))
    return subs


def flat_dict(config, skip=(), later=None, as_lists: bool = True) -> dict:
    """``config``'s fields by name (but ``skip``), tuples as lists (``as_lists``), each group's fields under their old flat names
    (:func:`grouped`; a field without one as ``group.field``) where the group stood, but those ``later`` names (field -> flat names) after that field: a
    group whose fields stood apart is recorded in the old order."""
    subs = flat_names(type(config))
    later = later or {}
    moved = {old for names in later.values() for old in names}
    flat = {}
    for name, value in config.__dict__.items():
        if name in skip:
            continue
        if name in subs:
            flat.update({old: getattr(value, sub) for old, sub in subs[name]})
            named = {sub for _, sub in subs[name]}  # a field added to the group since has no flat name: group.field
            flat.update(
                {f"{name}.{f.name}": getattr(value, f.name) for f in dataclasses.fields(value) if f.name not in named}
            )
        else:
            flat[name] = value
    flat = {k: listed(v) for k, v in flat.items()} if as_lists else flat
    out = {}
    for name, value in flat.items():
        if name not in moved:
            out[name] = value
        out.update({old: flat[old] for old in later.get(name, ())})
    return out


def flat_value(config, name: str):
    """``config``'s field ``name``, or a group's field by its old flat name (:func:`grouped`) read from its group, not
    through the deprecated attribute."""
    a = getattr(type(config), "renamed_fields", {}).get(name)
    if a is None or a.sub is None:
        return getattr(config, name)
    return getattr(getattr(config, a.field), a.sub)


def _default(cls, name):
    f = cls.__dataclass_fields__[name]
    if f.default is not dataclasses.MISSING:
        return f.default
    return f.default_factory()


def renamed_fields(**aliases: Alias):
    """Class decorator (above ``@dataclass``): keep the old field names ``aliases`` working."""

    def wrap(cls):
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kwargs):
            for old, a in aliases.items():
                if old not in kwargs:
                    continue
                value = kwargs.pop(old)
                new = a.field if a.sub is None else f"{a.field}.{a.sub}"
                warnings.warn(f"{cls.__name__}: '{old}' is deprecated, use '{new}'", DeprecationWarning, stacklevel=2)
                current = kwargs.get(a.field, _default(cls, a.field))
                kwargs[a.field] = value if a.put is None else a.put(current, value, kwargs)
            init(self, *args, **kwargs)

        cls.__init__ = __init__
        for old, a in aliases.items():

            def getter(self, a=a):
                value = getattr(self, a.field)
                return value if a.get is None else a.get(value)

            def setter(self, value, a=a):
                setattr(self, a.field, value if a.put is None else a.put(getattr(self, a.field), value, vars(self)))

            new = a.field if a.sub is None else f"{a.field}.{a.sub}"
            setattr(cls, old, property(getter, setter, doc=f"Deprecated name of ``{new}``."))
        cls.renamed_fields = dict(aliases)
        return cls

    return wrap
