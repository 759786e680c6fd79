"""The bad-input matrix as tests: every misuse of a public call of operators, sensor,
metrics, scenes, bucket and experiment must be refused clearly or answered correctly
(``tests/reliability/matrix.py`` defines the cases and the classes)."""

from __future__ import annotations

import pytest

from .matrix import cases, classify
from .specs import OUTSIDE, SPECS

#: Failing cases in modules outside this suite's scope, as (spec name, case kind): they are
#: expected to fail (strict, so they flip when fixed). Listed in docs/reliability.md.
KNOWN_OUTSIDE = {
}

_CASES = cases(SPECS)
_OUTSIDE = cases(OUTSIDE)


@pytest.mark.parametrize("case", _CASES, ids=[c.id for c in _CASES])
def test_bad_input_is_refused_clearly_or_answered_correctly(case):
    cls, detail = classify(case)
    assert cls in ("clear", "correct"), f"{cls}: {detail}"


def _outside_param(c):
    reason = KNOWN_OUTSIDE.get((c.spec.name, c.kind))
    marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
    return pytest.param(c, marks=marks, id=c.id)


@pytest.mark.parametrize("case", [_outside_param(c) for c in _OUTSIDE])
def test_outside_modules(case):
    cls, detail = classify(case)
    assert cls in ("clear", "correct"), f"{cls}: {detail}"


def test_matrix_covers_every_module():
    mods = {c.spec.module for c in _CASES}
    assert mods == {"operators", "sensor", "metrics", "scenes", "bucket", "experiment"}
    assert len(_CASES) > 700


def test_huge_sizes_are_refused_before_allocating():
    # sizes no machine holds: refused with an estimate, never a MemoryError or a swap storm
    from torchtof import scenes, sensor
    from torchtof.operators import random_binary_patterns

    for call in (lambda: scenes.sky_character(1 << 20), lambda: sensor.dust_map(1 << 22),
                 lambda: sensor.area_overlap_matrix(1 << 22, 1 << 22),
                 lambda: random_binary_patterns(1 << 20, 1 << 12)):
        with pytest.raises(ValueError, match="needs about .* more than the memory limit"):
            call()
