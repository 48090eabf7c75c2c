"""PCG2D: the slide's integer algorithm bit for bit, and uniform floats."""
import numpy as np

from ember.kernels.rng import PathRng, pcg2d, seed_paths, to_unit_float
from stats import assert_chi2

M32 = 0xFFFFFFFF


def slide_pcg2d(x: int, y: int):
    """The GLSL get_random_numbers from the lecture, in Python integers mod 2^32."""
    x = (1664525 * x + 1013904223) & M32
    y = (1664525 * y + 1013904223) & M32
    x = (x + 1664525 * y) & M32
    y = (y + 1664525 * x) & M32
    x ^= x >> 16
    y ^= y >> 16
    x = (x + 1664525 * y) & M32
    y = (y + 1664525 * x) & M32
    x ^= x >> 16
    y ^= y >> 16
    return x, y


def test_pcg2d_matches_the_slide_bit_for_bit():
    rng = np.random.default_rng(1)
    xs = np.concatenate([[0, 1, 2, 65536, M32, 0x80000000], rng.integers(0, 2**32, 500)]).astype(np.uint32)
    ys = np.concatenate([[0, 0, 7, 3, M32, 1], rng.integers(0, 2**32, 500)]).astype(np.uint32)
    gx, gy = pcg2d(xs, ys)
    for i in range(len(xs)):
        assert (int(gx[i]), int(gy[i])) == slide_pcg2d(int(xs[i]), int(ys[i]))
    # Known values, pinned so that a change to the mixing can never pass unnoticed.
    assert slide_pcg2d(0, 0) == (417608103, 90043601)
    gx, gy = pcg2d(np.array([0, 1], np.uint32), np.array([0, 2], np.uint32))
    assert list(gx) == [417608103, 45825804] and list(gy) == [90043601, 214070181]


def test_state_is_updated_and_reused_like_the_slides_inout_seed():
    rng = PathRng(np.array([5], np.uint32), np.array([9], np.uint32))
    first = rng.next_2d()
    x1, y1 = slide_pcg2d(5, 9)
    assert (int(rng.x[0]), int(rng.y[0])) == (x1, y1)
    rng.next_2d()
    assert (int(rng.x[0]), int(rng.y[0])) == slide_pcg2d(x1, y1)
    assert first[0][0] == np.float32((x1 >> 9) / 2**23)


def test_floats_are_in_unit_interval_even_for_the_largest_integer():
    bits = np.array([0, 1, 511, 512, M32], np.uint32)
    f = to_unit_float(bits)
    assert f.dtype == np.float32
    assert f[0] == 0.0 and f[-1] < 1.0 and np.all(f >= 0)


def test_seed_follows_the_slide_and_differs_per_pixel_pass_and_user_seed():
    x, y = seed_paths(np.array([3, 4], np.uint32), 2, user_seed=0)
    assert list(x) == [3 + 2 * 65536, 4 + 2 * 65536]
    # Pixel p + 2^16 at pass k and pixel p at pass k + 1 share x: y must tell them apart.
    xa, ya = seed_paths(np.array([65536 + 3], np.uint32), 0, 0)
    xb, yb = seed_paths(np.array([3], np.uint32), 1, 0)
    assert xa[0] == xb[0] and ya[0] != yb[0]
    _, y7 = seed_paths(np.array([3], np.uint32), 0, 7)
    assert y7[0] != seed_paths(np.array([3], np.uint32), 0, 0)[1][0]


def test_uniformity_chi_square_2d():
    pixels = np.arange(200_000, dtype=np.uint32)
    rng = PathRng(*seed_paths(pixels, 0, 1234))
    for _ in range(3):  # the first, second and third draw of each path
        u, v = rng.next_2d()
        counts, _, _ = np.histogram2d(u, v, bins=32, range=[[0, 1], [0, 1]])
        assert_chi2(counts, np.full_like(counts, len(u) / counts.size))


def test_consecutive_passes_are_not_correlated():
    """The same pixel over successive passes: first draws uniform in 1-D bins."""
    passes = np.arange(100_000, dtype=np.uint32)
    x, y = seed_paths(np.full(len(passes), 12345, np.uint32), passes, 0)
    u, _ = PathRng(x, y).next_2d()
    counts, _ = np.histogram(u, bins=100, range=(0, 1))
    assert_chi2(counts, np.full(100, len(u) / 100))


def test_stratified_sequence_is_uniform_across_pixels_and_even_within_a_pixel():
    from ember.kernels.rng import stratified_2d
    # Across pixels, one sample index: independent uniform numbers (the rotations are PCG2D hashes).
    pixels = np.arange(100_000, dtype=np.uint32)
    u, v = stratified_2d(pixels, np.full(len(pixels), 7, np.uint32), 3, dimension=2)
    counts, _, _ = np.histogram2d(u, v, bins=16, range=[[0, 1], [0, 1]])
    assert_chi2(counts, np.full_like(counts, len(u) / counts.size))
    # Within a pixel, successive samples fill the square far more evenly than independent ones:
    # over 16x16 cells, 1024 samples leave a count variance well below the binomial one (about 4).
    u, v = stratified_2d(np.full(1024, 12345, np.uint32), np.arange(1024, dtype=np.uint32), 3, dimension=0)
    counts, _, _ = np.histogram2d(u, v, bins=16, range=[[0, 1], [0, 1]])
    assert counts.var() < 1.0
    # Dimension pairs of one pixel are independent, not the same sequence shifted: the light choice
    # must not be tied to the point on the light. Bin (u of dimension 0, u of dimension 1): all cells fill.
    u2, _ = stratified_2d(np.full(1024, 12345, np.uint32), np.arange(1024, dtype=np.uint32), 3, dimension=1)
    joint, _, _ = np.histogram2d(u, u2, bins=8, range=[[0, 1], [0, 1]])
    assert_chi2(joint, np.full_like(joint, 1024 / 64))


def test_index_scramble_keeps_power_of_two_blocks_together():
    """The first 2^k scrambled indices are 2^k distinct indices of one aligned block: for the R2
    sequence any such block is the first one rotated, so each prefix stays evenly spread."""
    from ember.kernels.rng import nested_uniform_scramble, reverse_bits
    assert reverse_bits(np.uint32([1]))[0] == 2 ** 31 and reverse_bits(np.uint32([6]))[0] == 0x60000000
    for seed in (1, 12345, 0xDEADBEEF):
        for k in (4, 6, 10):
            out = nested_uniform_scramble(np.arange(2 ** k, dtype=np.uint32), np.full(2 ** k, seed, np.uint32))
            assert len(np.unique(out)) == 2 ** k
            assert len(np.unique(out >> np.uint32(k))) == 1  # one aligned block
        a = nested_uniform_scramble(np.arange(16, dtype=np.uint32), np.full(16, seed, np.uint32))
        b = nested_uniform_scramble(np.arange(16, dtype=np.uint32), np.full(16, seed + 1, np.uint32))
        assert not np.array_equal(a, b)


def test_sample_zero_looks_through_the_pixel_centre():
    """As Cycles' init_from_camera: sample 0 of each pixel has no jitter (NEE_MIS's stratified numbers);
    the other samples keep theirs, and the PCG2D stream (LECTURE, COSINE: strata None) is untouched."""
    from ember.kernels.samples import Samples
    pixel = np.arange(8, dtype=np.uint32)
    index = np.array([0, 1, 0, 5, 0, 2, 3, 0], np.uint32)
    jx, jy = Samples(PathRng(*seed_paths(pixel, 0, 0)), (pixel, index), 0, nee=True).camera()
    zero = index == 0
    assert jx.dtype == np.float32 and (jx[zero] == 0.5).all() and (jy[zero] == 0.5).all()
    assert (jx[~zero] != 0.5).all() and (jy[~zero] != 0.5).all()
    plain = Samples(PathRng(*seed_paths(pixel, 0, 0)), None, 0, nee=True).camera()
    expected = PathRng(*seed_paths(pixel, 0, 0)).next_2d()
    np.testing.assert_array_equal(plain[0], expected[0])
    np.testing.assert_array_equal(plain[1], expected[1])
