"""Reading scene YAML within bounds: scene files are input from anywhere (design §10).

A scene file or ``--set`` value is parsed by a safe loader that refuses, while
parsing, what would make loading unbounded: more than :data:`MAX_SCENE_BYTES`,
aliases (``*name``: a few lines of nested aliases expand to gigabytes), nesting
deeper than :data:`MAX_NESTING`, integer literals too long to be any field's
value, more than :data:`MAX_NODES` values in all.  It reads ``1e-5`` as a float, as
YAML 1.2 does.  Every failure is a :class:`SceneError` on one line; values are quoted
shortened.

With libyaml (PyYAML's C extension, ``yaml.__with_libyaml__``) the file is parsed in C:
the pure-Python parser costs about 40 us of CPU per value (a 690 kB file of 50,000
waypoints took 12 s), libyaml about 1 us.  The checks then run on libyaml's event
stream before anything is built, and only the construction of Python values (whose
count :data:`MAX_NODES` bounds) runs in Python.
"""

from __future__ import annotations

import re
import reprlib
from typing import Any

import yaml

__all__ = ["SceneError", "MAX_SCENE_BYTES", "MAX_NESTING", "MAX_NODES", "HugeInteger",
           "load_yaml", "shorten"]

#: Largest scene file (bytes); also the longest ``--set`` value.
MAX_SCENE_BYTES = 1_000_000
#: Deepest nesting of mappings and lists (a scene needs 5: grasps[i].waypoints[j][k]).
MAX_NESTING = 16
#: Most values (scalars, lists and mappings) in one document: a scene of 32 grasps,
#: 32 obstacles, 64 pins and 5,000 waypoint rows (``budget.MAX_WAYPOINTS``) has about
#: 35,000.  Building each costs Python a few microseconds, so this bounds loading.
MAX_NODES = 50_000
# An integer scalar longer than this is refused by field name without being
# converted (Python refuses to convert more than 4300 digits anyway).
_MAX_INTEGER_CHARS = 100


class SceneError(ValueError):
    """A scene file or override is malformed; the message names the field."""


_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 60
_REPR.maxlong = 40
_REPR.maxlist = _REPR.maxtuple = 6
_REPR.maxdict = 4
_REPR.maxlevel = 3


def shorten(value: Any) -> str:
    """``repr`` for error messages, shortened: never the whole of a big value."""
    return _REPR.repr(value)


class HugeInteger:
    """An integer scalar too long to be any field's value; kept (unconverted)
    so that the field it was given for is named in the refusal."""

    def __init__(self, text: str):
        self.digits = len(text.lstrip("+-"))

    def __repr__(self) -> str:
        return f"<an integer of {self.digits} digits>"


def _too_many(mark) -> SceneError:
    return SceneError(f"line {mark.line + 1}: more than {MAX_NODES:,} values (a scene "
                      "needs far fewer; see the scene limits)")


def _alias(event) -> SceneError:
    return SceneError(f"line {event.start_mark.line + 1}: YAML aliases "
                      f"(*{event.anchor[:40]}) are not allowed in scene files; "
                      "write the values out")


def _too_deep(mark) -> SceneError:
    return SceneError(f"line {mark.line + 1}: nested more than {MAX_NESTING} "
                      "levels deep (a scene needs at most 5)")


class _SceneConstructor:
    """What both loaders build differently from PyYAML's safe loader: keys must be
    unique, and integers too long for any field are kept unconverted."""

    def construct_mapping(self, node, deep=False):
        # YAML requires a mapping's keys to be unique; PyYAML keeps the last
        # silently, so a scene with two `material:` sections ran with one of
        # them dropped.  Refused, naming both lines.
        first = {}
        for key_node, _ in node.value:
            if isinstance(key_node, yaml.ScalarNode):
                line = key_node.start_mark.line + 1
                if key_node.value in first:
                    raise SceneError(f"line {line}: key {shorten(key_node.value)} appears "
                                     f"twice in one mapping (first at line "
                                     f"{first[key_node.value]}); keys must be unique")
                first[key_node.value] = line
        return super().construct_mapping(node, deep)

    def construct_yaml_int(self, node):
        if len(node.value) > _MAX_INTEGER_CHARS:
            return HugeInteger(node.value)
        return super().construct_yaml_int(node)


class _SceneLoader(_SceneConstructor, yaml.SafeLoader):
    """Safe YAML loader for scene files, pure Python (used without libyaml).

    It reads ``1e-5`` as a float (PyYAML follows YAML 1.1, where a float needs a
    dot, ``1.0e-5``; YAML 1.2 and every user's expectation accept ``1e-5``), and
    it refuses, while parsing, what would make loading unbounded: aliases
    (``*name``; a few lines of nested aliases expand to gigabytes), nesting
    deeper than :data:`MAX_NESTING` and more than :data:`MAX_NODES` values.
    """

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            raise _alias(self.peek_event())
        self._nodes += 1
        if self._nodes > MAX_NODES:
            raise _too_many(self.peek_event().start_mark)
        self._depth += 1
        try:
            if self._depth > MAX_NESTING and not self.check_event(yaml.ScalarEvent):
                raise _too_deep(self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


_FAST = bool(getattr(yaml, "__with_libyaml__", False))
_LOADERS = [_SceneLoader]
if _FAST:
    class _FastSceneLoader(_SceneConstructor, yaml.CSafeLoader):
        """The same loader with libyaml's parser and composer (see the module text);
        :func:`_check_events` makes the checks first."""

    _FastSceneLoader.add_constructor("tag:yaml.org,2002:int",
                                     _FastSceneLoader.construct_yaml_int)
    _LOADERS.append(_FastSceneLoader)


def _check_events(text) -> None:
    """Refuse aliases, deep nesting and too many values from libyaml's events,
    before any node is composed (an alias bomb is a few events)."""
    depth = nodes = 0
    starts, ends = (yaml.MappingStartEvent, yaml.SequenceStartEvent), (
        yaml.MappingEndEvent, yaml.SequenceEndEvent)
    events = yaml.parse(text, Loader=yaml.CSafeLoader)
    while True:
        try:
            event = next(events, None)
        except yaml.MarkedYAMLError as exc:
            # libyaml's scanner reads ahead and stops at 1000 levels by itself
            if "nesting depth" in str(exc.problem) and exc.problem_mark is not None:
                raise _too_deep(exc.problem_mark) from None
            raise
        if event is None:
            return
        if isinstance(event, yaml.ScalarEvent):
            nodes += 1
        elif isinstance(event, starts):
            nodes += 1
            depth += 1
            if depth > MAX_NESTING:
                raise _too_deep(event.start_mark)
        elif isinstance(event, ends):
            depth -= 1
        elif isinstance(event, yaml.AliasEvent):
            raise _alias(event)
        if nodes > MAX_NODES:
            raise _too_many(event.start_mark)


_SceneLoader.add_constructor("tag:yaml.org,2002:int", _SceneLoader.construct_yaml_int)
for _loader in _LOADERS:
    _loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                     |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                     |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                     |[-+]?\.(?:inf|Inf|INF)
                     |\.(?:nan|NaN|NAN))$""", re.X),
        list("-+0123456789."))


def load_yaml(text: str | bytes, where: str):
    """Parse scene YAML; every failure is a :class:`SceneError` starting ``where: ``."""
    if len(text) > MAX_SCENE_BYTES:
        raise SceneError(f"{where}: larger than {MAX_SCENE_BYTES} bytes, the most a "
                         "scene may have")
    try:
        if _FAST:
            _check_events(text)
            return yaml.load(text, Loader=_FastSceneLoader)  # noqa: S506 - safe loader subclass
        return yaml.load(text, Loader=_SceneLoader)  # noqa: S506 - safe loader subclass
    except SceneError as exc:
        raise SceneError(f"{where}: {exc}") from None
    except yaml.YAMLError as exc:
        raise SceneError(f"{where}: not valid YAML: {_yaml_problem(exc)}") from None
    except RecursionError:
        raise SceneError(f"{where}: nested too deeply") from None


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """PyYAML's error on one line: problem, where, and what it was parsing."""
    def at(mark):
        return f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
    if isinstance(exc, yaml.MarkedYAMLError) and exc.problem:
        text = exc.problem + at(exc.problem_mark)
        if exc.context:
            text += f" ({exc.context}{at(exc.context_mark)})"
    else:
        text = " ".join(str(exc).split())
    return text if len(text) <= 300 else text[:297] + "..."
