"""YAML read with limits (srmosaic_ros/bounded_yaml.py): aliases, depth, size; short previews."""
from __future__ import annotations

import pytest
import yaml

from srmosaic_ros.bounded_yaml import MAX_DEPTH, LimitError, load_bounded, preview


def test_plain_documents_load_as_with_the_safe_loader() -> None:
    text = 'a:\n  b: [1, 2.5, "x"]\n  c: {d: true, e: .nan}\n  f: &anchor 3\n'
    assert load_bounded(text)['a']['b'] == yaml.safe_load(text)['a']['b']


def test_an_alias_is_refused_where_it_is() -> None:
    with pytest.raises(LimitError, match=r'alias \(\*a\) is not allowed') as info:
        load_bounded('x: &a [1, 2]\ny: *a\n')
    assert info.value.problem_mark.line == 1


@pytest.mark.parametrize('depth', [MAX_DEPTH + 1, 5000])
def test_deep_nesting_is_refused_without_recursion(depth: int) -> None:
    with pytest.raises(LimitError, match=f'nested more than {MAX_DEPTH} deep'):
        load_bounded('x: ' + '[' * depth + ']' * depth)
    load_bounded('x: ' + '[' * (MAX_DEPTH - 1) + ']' * (MAX_DEPTH - 1))


def test_a_preview_is_short() -> None:
    assert len(preview(list(range(100000)))) <= 60
    assert len(preview('x' * 10000)) <= 60
    assert preview(5) == '5'
