"""Expected outcomes of (scene, integrator) combinations, and how a refusal is recognised.

- ``PASS``: the integrator renders and the comparison with ``path`` passes;
- :class:`Refused` ``(pattern, reason)``: the integrator must raise an error whose
  message matches the regular expression ``pattern`` (it must name the offending shape,
  emitter or parameter); any other error, or a render, is not this outcome;
- :class:`NotApplicable` ``(reason)``: the method does not cover the scene by design
  (documented); the combination is not run.
"""
import re
from dataclasses import dataclass

PASS = "PASS"
FAIL = "FAIL"
REFUSED = "REFUSED"
NA = "N/A"


@dataclass(frozen=True)
class Refused:
    pattern: str
    reason: str = ""

    def matches(self, message):
        return re.search(self.pattern, message, flags=re.S) is not None

    def __str__(self):
        return "REFUSED /%s/" % self.pattern


@dataclass(frozen=True)
class NotApplicable:
    reason: str

    def __str__(self):
        return "N/A: " + self.reason


def expected_label(expected):
    """PASS, REFUSED or N/A for an expectation (PASS, Refused or NotApplicable)."""
    if isinstance(expected, Refused):
        return REFUSED
    if isinstance(expected, NotApplicable):
        return NA
    return PASS


def error_chain(exc):
    """The exception and its causes (Mitsuba wraps errors raised inside a Python
    integrator's render() as the __cause__ of a RuntimeError), outermost first."""
    chain, seen = [], set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        chain.append(exc)
        exc = exc.__cause__ or exc.__context__
    return chain


def describe_error(exc):
    """(full text of the chain for pattern matching, one line naming the innermost error)."""
    chain = error_chain(exc)
    text = "\n".join("%s: %s" % (type(e).__name__, e) for e in chain)
    inner = chain[-1]
    message = str(inner).strip()
    if isinstance(inner, KeyError):
        message = repr(inner.args[0]) if inner.args else ""
    first = message.splitlines()[0] if message else ""
    return text, "%s: %s" % (type(inner).__name__, first[:300])
