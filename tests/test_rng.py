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
    """The first 2^k scrambled indices are 2^k distinct indices of one aligned block: for the Sobol
    sequence any such block is a (0, k, 2)-net, so each prefix stays evenly spread."""
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
    jx, jy = Samples(PathRng(*seed_paths(pixel, 0, 0)), (pixel, index, index), 0, nee=True).camera()
    zero = index == 0
    assert jx.dtype == np.float32 and (jx[zero] == 0.5).all() and (jy[zero] == 0.5).all()
    assert (jx[~zero] != 0.5).all() and (jy[~zero] != 0.5).all()
    plain = Samples(PathRng(*seed_paths(pixel, 0, 0)), None, 0, nee=True).camera()
    expected = PathRng(*seed_paths(pixel, 0, 0)).next_2d()
    np.testing.assert_array_equal(plain[0], expected[0])
    np.testing.assert_array_equal(plain[1], expected[1])


def _sobol_2d(index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The first two Sobol dimensions at uint32 indices, as uint32 fixed point, from their definition: the
    van der Corput sequence (bit reversal), and the xor of the direction numbers v_k of the index's set bits
    k, v_0 = 2^31, v_k = v_(k-1) xor v_(k-1) / 2 (primitive polynomial x + 1). The oracle the kernel's
    table-free second dimension (rng.sobol_y_reversed) is checked against."""
    from ember.kernels.rng import reverse_bits
    index = np.asarray(index, np.uint32)
    v, y = np.uint32(1 << 31), np.zeros_like(index)
    for k in range(32):
        y ^= np.where((index >> np.uint32(k)) & np.uint32(1), v, np.uint32(0))
        v = v ^ (v >> np.uint32(1))
    return reverse_bits(index), y


def _is_net(u: np.ndarray, v: np.ndarray, k: int) -> bool:
    """Whether 2^k points put exactly one point in every box of every 2^a x 2^(k-a) grid of the square."""
    for a in range(k + 1):
        i = np.floor(np.asarray(u, np.float64) * 2 ** a).astype(int)
        j = np.floor(np.asarray(v, np.float64) * 2 ** (k - a)).astype(int)
        if len(np.unique(i * 2 ** (k - a) + j)) != 2 ** k:
            return False
    return True


def test_each_pixels_first_power_of_two_samples_form_a_net():
    """Sobol's first two dimensions, and every pixel's shuffled and Owen-scrambled sequence of a dimension
    pair: each prefix of 2^k samples is a (0, k, 2)-net, the stratification of Cycles' Sobol patterns.
    Independent random numbers almost never are (checked: seed 0's first 64)."""
    from ember.kernels.rng import stratified_2d, to_unit_float
    for k in (4, 6, 10):
        x, y = _sobol_2d(np.arange(2 ** k, dtype=np.uint32))
        assert _is_net(to_unit_float(x), to_unit_float(y), k)
        for pixel, dimension in ((0, 0), (12345, 2), (2 ** 31 + 7, 4)):
            u, v = stratified_2d(np.full(2 ** k, pixel, np.uint32), np.arange(2 ** k, dtype=np.uint32), 3, dimension)
            assert _is_net(u, v, k)
    # Samples 64..127 too (an aligned block), and high indices through the second table.
    u, v = stratified_2d(np.full(64, 99, np.uint32), np.arange(64, 128, dtype=np.uint32), 0, 1)
    assert _is_net(u, v, 6)
    x, y = _sobol_2d(np.arange(2 ** 20, 2 ** 20 + 256, dtype=np.uint32))
    assert _is_net(to_unit_float(x), to_unit_float(y), 8)
    rng = np.random.default_rng(0)
    assert not _is_net(rng.random(64), rng.random(64), 6)


def test_sobol_second_dimension_without_tables():
    """sobol_y_reversed (Pascal's triangle mod 2 by shifts) is the dimension from its direction numbers,
    reversed, bit for bit."""
    from ember.kernels.rng import reverse_bits, sobol_y_reversed
    index = np.concatenate([np.arange(1 << 16, dtype=np.uint32),
                            np.random.default_rng(3).integers(0, 1 << 32, 1 << 16, dtype=np.uint64).astype(np.uint32)])
    np.testing.assert_array_equal(sobol_y_reversed(index), reverse_bits(_sobol_2d(index)[1]))


def _strata_points(pattern, width, height, length, seed=7, ranged=False, first=False, dimension=None):
    """The numbers of one dimension (CAMERA unless given) of every sample of a width x height image laid out
    by samples.sample_strata: (u, v) arrays of shape (height, width, length)."""
    from ember.kernels.rng import stratified_2d
    from ember.kernels.samples import CAMERA, sample_strata
    row, col = np.divmod(np.repeat(np.arange(width * height), length), width)
    sample = np.tile(np.arange(length, dtype=np.uint32), width * height)
    pixel_index = (row * width + col).astype(np.uint32)
    pixel, _, index = sample_strata(pattern, seed, width, height, length, row.astype(np.int32),
                                    col.astype(np.int32), pixel_index, sample, ranged=ranged, first=first)
    u, v = stratified_2d(pixel, index, seed, CAMERA if dimension is None else dimension)
    return u.reshape(height, width, length), v.reshape(height, width, length)


def test_blue_noise_layout_stratifies_neighbouring_pixels_together():
    """AUTOMATIC (Cycles' blue-noise pattern): every pixel's samples are still a (0, m, 2)-net, and the
    samples of each aligned 2x2 and 4x4 square of pixels together are one too (4 and 16 times finer), which
    is what makes neighbours' errors blue noise. SOBOL_BURLEY's independent pixels almost never are (a
    square's union is a net by chance with probability far below 1e-6 at these sizes)."""
    m, width, height = 4, 12, 8          # 16 samples; an image whose sides are not powers of two
    u, v = _strata_points("AUTOMATIC", width, height, 2 ** m)
    for y in range(height):
        for x in range(width):
            assert _is_net(u[y, x], v[y, x], m)
    for size, k in ((2, m + 2), (4, m + 4)):
        for y in range(0, height - size + 1, size):
            for x in range(0, width - size + 1, size):
                assert _is_net(u[y:y + size, x:x + size].ravel(), v[y:y + size, x:x + size].ravel(), k), (x, y)
    # The places are distinct: no two pixels read the same samples.
    pixels = np.stack([u, v], -1).reshape(width * height, -1)
    assert len(np.unique(pixels, axis=0)) == width * height
    # A wave's pixels laid out once each (repeats: their samples are consecutive paths), the same numbers.
    from ember.kernels.samples import sample_strata
    row, col = (a.astype(np.int32) for a in np.divmod(np.repeat(np.arange(width * height), 16), width))
    sample = np.tile(np.arange(16, dtype=np.uint32), width * height)
    pixel_index = (row * width + col).astype(np.uint32)
    for first in (False, True):
        once = sample_strata("AUTOMATIC", 7, width, height, 16, row, col, pixel_index, sample, first=first)
        each = sample_strata("AUTOMATIC", 7, width, height, 16, row, col, pixel_index, sample, first=first,
                             repeats=16)
        for a, b in zip(once, each):
            np.testing.assert_array_equal(a, b)
    su, sv = _strata_points("SOBOL_BURLEY", width, height, 2 ** m)
    for y in range(height):
        for x in range(width):
            assert _is_net(su[y, x], sv[y, x], m)
    squares = [_is_net(su[y:y + 2, x:x + 2].ravel(), sv[y:y + 2, x:x + 2].ravel(), m + 2)
               for y in range(0, height, 2) for x in range(0, width, 2)]
    assert not any(squares)


def test_blue_noise_layout_falls_back_to_a_sequence_per_pixel():
    """Where the pixels' places times the sample count overflow the sequence's 2^32 numbers, and for a
    range of a frame's samples, AUTOMATIC lays the samples out as SOBOL_BURLEY does, number for number."""
    from ember.kernels.samples import sample_strata
    row, col = np.zeros(4, np.int32), np.arange(4, dtype=np.int32)
    sample = np.arange(4, dtype=np.uint32)
    pixel_index = col.astype(np.uint32)
    own = sample_strata("SOBOL_BURLEY", 1, 4096, 4096, 1 << 8, row, col, pixel_index, sample)
    for args, ranged in (((4096, 4096, 1 << 8), False),      # 2^24 places x 2^8 samples: fits
                         ((4096, 4096, (1 << 8) + 1), False),  # one sample more: does not
                         ((64, 64, 16), True)):
        got = sample_strata("AUTOMATIC", 1, *args, row, col, pixel_index, sample, ranged=ranged)
        fits = args[0] * args[1] * args[2] <= (1 << 32) and not ranged
        assert (got[0] is not pixel_index) == fits
        if not fits:
            for a, b in zip(got, own):
                np.testing.assert_array_equal(a, b)


def test_the_viewports_first_sample_is_blue_noise_on_its_own():
    """first (the viewport's pattern, Cycles' Blue-Noise First): sample 0 of the pixels of every aligned 2x2
    and 4x4 square together is a (0, 2, 2)- and (0, 4, 2)-net, so the first image's noise is blue on its own;
    samples 1..16 of each pixel are still a (0, 4, 2)-net; without it, the first samples of a square are
    not (they are the first of 17-sample segments)."""
    from ember.kernels.samples import LIGHT
    width, height = 8, 8
    u, v = _strata_points("AUTOMATIC", width, height, 17, first=True, dimension=LIGHT)
    for size, k in ((2, 2), (4, 4)):
        for y in range(0, height, size):
            for x in range(0, width, size):
                assert _is_net(u[y:y + size, x:x + size, 0].ravel(), v[y:y + size, x:x + size, 0].ravel(), k)
    for y in range(height):
        for x in range(width):
            assert _is_net(u[y, x, 1:], v[y, x, 1:], 4)
    pu, pv = _strata_points("AUTOMATIC", width, height, 17, dimension=LIGHT)
    assert not all(_is_net(pu[y:y + 2, x:x + 2, 0].ravel(), pv[y:y + 2, x:x + 2, 0].ravel(), 2)
                   for y in range(0, height, 2) for x in range(0, width, 2))
