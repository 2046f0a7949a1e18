"""City styles: the default stays byte-identical; dense, downtown and industrial regions."""

import hashlib
import json

import pytest

from meta_sim.sim.layout import generate_layout

# sha256 of the sorted JSON of default layouts, taken before city styles existed: published
# benchmarks and caches depend on the default city never changing.
DEFAULT_HASHES = {
    (0, 400.0, 300.0): "8cf954ea4158d2ef6908ab8f992ed1aec1a6d78b44bf88d1144d7a3a0f59587f",
    (0, 345.6, 345.6): "b8853d4e55deb5da8a4b8ae8f12a544f964a5a15a048d80f58eaa72ca3f8ce70",
    (1, 400.0, 300.0): "f781d59ac2955262b0374c60f0866c15a9ecad57c02def1d48c4648572d19f48",
    (1, 345.6, 345.6): "082a3591a80fbf9bc557f1d8561e01ec71d4328bceb95a20264545aba88f6968",
    (7, 400.0, 300.0): "76b218b4ee4016ff643c5863d295ad9062caaad6e96a3fbe2bac5a0c4266620b",
    (7, 345.6, 345.6): "7f6c2d470c495c33fe6cd749362ce1226df6501eb341d41171f6da7c54bcad7f",
}


def _digest(layout):
    return hashlib.sha256(json.dumps(layout.to_dict(), sort_keys=True).encode()).hexdigest()


@pytest.mark.parametrize("seed,width,height", sorted(DEFAULT_HASHES))
def test_default_layouts_are_byte_identical_to_before_styles(seed, width, height):
    assert _digest(generate_layout(seed, width, height)) == DEFAULT_HASHES[(seed, width, height)]
