"""worker/keys.py content_key: the one content address of precomputed parts and caches. A key
must change with anything a part depends on (values, dtype, shape, kind, format version) and
only then (not with the order parts are named in)."""
import numpy as np
import pytest

from worker.keys import content_key


def test_a_key_changes_with_every_input_and_only_then():
    a = np.arange(12, dtype=np.float32).reshape(4, 3)
    k = content_key("cuts", 2, vertices=a, tau=1.0, height=15)
    assert len(k) == 32 and set(k) <= set("0123456789abcdef")
    assert content_key("cuts", 2, height=15, tau=1.0, vertices=a.copy()) == k      # order of names
    assert content_key("cuts", 2, vertices=np.asfortranarray(a), tau=1.0, height=15) == k   # memory layout
    others = [content_key("ground", 2, vertices=a, tau=1.0, height=15),           # kind
              content_key("cuts", 3, vertices=a, tau=1.0, height=15),             # format version
              content_key("cuts", 2, vertices=a.astype(np.float64), tau=1.0, height=15),   # dtype
              content_key("cuts", 2, vertices=a.reshape(3, 4), tau=1.0, height=15),        # shape
              content_key("cuts", 2, vertices=a + np.float32(1e-6), tau=1.0, height=15),   # a value
              content_key("cuts", 2, vertices=a, tau=1.0 + 1e-15, height=15),     # a float, exactly
              content_key("cuts", 2, vertices=a, tau=1.0, height=16),
              content_key("cuts", 2, normals=a, tau=1.0, height=15),              # a part's name
              content_key("cuts", 2, vertices=a, tau=1.0, height=15, extra=None)]
    assert len(set(others + [k])) == len(others) + 1


def test_fields_cannot_run_into_each_other():
    # length-prefixed fields: moving bytes from one part to the next is another key
    assert content_key("x", 1, a=b"ab", b=b"c") != content_key("x", 1, a=b"a", b=b"bc")
    assert content_key("x", 1, a="1", b="2") != content_key("x", 1, a="12")
    assert content_key("x", 1, a=[1, 2]) != content_key("x", 1, a="[1,2]")          # JSON vs text


def test_numpy_scalars_are_their_values_and_unkeyable_values_are_refused():
    assert content_key("x", 1, n=np.int64(15), t=np.float64(0.5)) == content_key("x", 1, n=15, t=0.5)
    assert content_key("x", 1, t=(1, 2)) == content_key("x", 1, t=[1, 2])
    with pytest.raises(ValueError):
        content_key("x", 1, t=float("nan"))
    with pytest.raises(TypeError):
        content_key("x", 1, t=object())
    with pytest.raises(TypeError):
        content_key("x", 1, t=np.array([object()]))
    with pytest.raises(ValueError):
        content_key("", 1)


def test_the_key_format_is_pinned():
    """Stored parts are found by these keys: a change of the hashing itself must come with a
    bump of every caller's format version, so this value may only change together with them."""
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    assert content_key("x", 1, a=a, t=0.1, s="s", b=b"\x00") == "e883c718203d6c77c72c981a56b0047c"
