

def test_misregistration_finds_a_shift_and_none_between_agreeing_views():
    from clearsplat.synth.textures import value_noise
    rng = np.random.default_rng(5)
    img = np.stack([value_noise(rng, (96, 128), cells=12) for _ in range(3)], -1)
    alpha = np.ones((96, 128))
    assert misregistration(img, img, alpha) == 0
    shifted = np.roll(img, (4, -2), axis=(0, 1))
    assert misregistration(img, shifted, alpha) == 4
    assert misregistration(img, np.roll(img, 6, axis=1), alpha) == 6
    # Nothing opaque to compare: 0.
    assert misregistration(img, shifted, alpha * 0) == 0
