"""Sinusoidal encodings of t and t_m (DECISIONS D3)."""

import numpy as np
import pytest

from jaxmac.encodings import EncodingConfig, sinusoid, time_encoding


def reference(pos, dim, base=10000.0):
    out = np.zeros((len(pos), dim))
    for p_i, p in enumerate(pos):
        for k in range(dim // 2):
            out[p_i, 2 * k] = np.sin(p / base ** (2 * k / dim))
            out[p_i, 2 * k + 1] = np.cos(p / base ** (2 * k / dim))
    return out


def test_sinusoid_matches_the_transformer_formula():
    pos = np.arange(0, 301, 7)
    for dim in (2, 8, 16):
        np.testing.assert_allclose(sinusoid(pos, dim), reference(pos, dim), atol=2e-4)
    np.testing.assert_array_equal(sinusoid(np.array(0), 8), [0, 1] * 4)
    # distinct integer times get distinct codes over a 300-step horizon
    codes = np.asarray(sinusoid(np.arange(301), 16))
    assert len(np.unique(codes.round(4), axis=0)) == 301


def test_time_encoding_concatenates_and_broadcasts():
    t = np.arange(5)
    t_m = np.array([[0, 1], [1, 0], [2, 1], [0, 2], [1, 0]])
    enc = time_encoding(t[:, None], t_m)
    assert enc.shape == (5, 2, 24)
    np.testing.assert_allclose(enc[..., :16], np.broadcast_to(reference(t, 16)[:, None], (5, 2, 16)), atol=1e-5)
    np.testing.assert_allclose(enc[..., 16:], reference(t_m.ravel(), 8).reshape(5, 2, 8), atol=1e-5)
    cfg = EncodingConfig(dim_t=4, dim_tm=6, use_t=False)
    assert cfg.dim == 6 and time_encoding(t, t, cfg).shape == (5, 6)
    np.testing.assert_allclose(time_encoding(t, t, cfg), reference(t, 6), atol=1e-5)


@pytest.mark.parametrize("kwargs", [dict(dim_t=15), dict(dim_tm=0), dict(dim_t=8.0), dict(base=1.0)])
def test_bad_encoding_config_raises(kwargs):
    with pytest.raises(ValueError, match="EncodingConfig"):
        EncodingConfig(**kwargs)
