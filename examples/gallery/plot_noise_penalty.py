"""
What the correction costs: noise-penalty maps
=============================================

A correction that brightens a dark corner or unmixes washed-out colours multiplies the noise there too. The
*noise penalty* is that factor, per bin and channel: how many times the corrected image's read noise is the raw
image's. The flat field alone costs the most where the vignetting is deepest; the unmixing costs more, most in
the corners, where the crosstalk is strongest. ``max_noise_penalty`` bounds it, at a small cost in colour that
the calibration reports.
"""

import matplotlib.pyplot as plt

import picamcal
from picamcal.simulate import make_camera, simulate_references

camera = make_camera("imx219", size=(320, 240))
references = simulate_references(camera, seed=1)
calibration = picamcal.calibrate(**references)
bounded = picamcal.calibrate(**references, max_noise_penalty=3.0)

maps = {
    "flat": calibration.noise_penalty("flat"),
    "centre": calibration.noise_penalty("centre"),
    "centre, bounded at 3": bounded.noise_penalty("centre"),
}
for name, penalty in maps.items():
    print(f"{name:22} worst {penalty.max():.2f}, median {float(sorted(penalty.ravel())[penalty.size // 2]):.2f}")

# %%
# The worst channel of each bin (the maps are bins of 16 x 16 pixels), on one colour scale.

top = max(float(penalty.max()) for penalty in maps.values())
figure, axes = plt.subplots(1, 3, figsize=(12, 3.2), layout="constrained")
for ax, (name, penalty) in zip(axes, maps.items(), strict=True):
    image = ax.imshow(penalty.max(axis=2), vmin=1, vmax=top, cmap="magma")
    ax.set_title(name)
    ax.set_axis_off()
figure.colorbar(image, ax=axes, label="noise penalty (x read noise)", shrink=0.9)
plt.show()
