"""The Examples sections of the optics modules run and give what they print."""

import doctest

import pytest

from simulate import fresnel, medium, microfacet, mie, phase


@pytest.mark.parametrize("module", [fresnel, mie, phase, medium, microfacet], ids=lambda m: m.__name__)
def test_module_examples(module):
    result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0
    assert result.failed == 0
