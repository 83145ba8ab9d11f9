"""Old names of config fields, kept working: one canonical name per weight (issues 26 and 57).

:func:`renamed_fields` decorates a dataclass config: each old name stays a keyword of the
constructor (mapped onto its canonical field, with a :class:`DeprecationWarning`) and an
attribute (a property reading and writing the canonical field). The old names are not
fields: ``dataclasses.fields``, ``replace`` and the config's ``to_dict`` see the canonical
names only.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from typing import Callable, NamedTuple, Optional

__all__ = ["Alias", "renamed_fields"]


class Alias(NamedTuple):
    """An old field name's mapping onto canonical field ``field``: ``get(canonical) -> old
    value``; ``put(canonical, old value, keywords) -> canonical`` (``keywords``: the
    constructor's other arguments, e.g. to check a length); both default to a plain rename."""

    field: str
    get: Optional[Callable] = None
    put: Optional[Callable] = None


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
                warnings.warn(
                    f"{cls.__name__}: '{old}' is deprecated, use '{a.field}'", DeprecationWarning, stacklevel=2
                )
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

            setattr(cls, old, property(getter, setter, doc=f"Deprecated name of ``{a.field}``."))
        cls.renamed_fields = dict(aliases)
        return cls

    return wrap
