"""
A flat field from a white alone
===============================

A microscope or a lens with a diffuser can often give only a white reference. From it picamcal measures the flat
field: the gain each channel needs in each bin to bring the white to its centre's level. Here the simulated
sensor's vignetting is moved off the centre of the frame (``tilt``), as a microscope's illumination often is;
the flat field follows it, and a line through the frame shows the white before and after.
"""

import matplotlib.pyplot as plt

import picamcal
from picamcal.simulate import make_camera, simulate_references

camera = make_camera("imx219", size=(320, 240), tilt=(4.0, 2.0))
references = simulate_references(camera, seed=1)
flat = picamcal.calibrate(references["white"], black=references["black"])  # a white alone
print(flat.kind, [mode.value for mode in flat.modes])

# %%
# A second white (another seed: independent noise), uncorrected and flat-fielded, along the middle row.

white = simulate_references(camera, seed=2)["white"]
before = picamcal.correct(white, flat, mode="uncorrected")
after = picamcal.correct(white, flat, mode="flat")
row = before.shape[0] // 2

figure, axes = plt.subplots(1, 2, figsize=(12, 3.4), layout="constrained")
for channel, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
    axes[0].plot(before[row, :, channel], color=colour, linewidth=0.8)
    axes[1].plot(after[row, :, channel], color=colour, linewidth=0.8)
for ax, title in zip(axes, ("uncorrected", "flat"), strict=True):
    ax.set_title(f"the white along row {row}, {title}")
    ax.set_xlabel("column (pixels)")
    ax.set_ylim(0, 1.3)
axes[0].set_ylabel("linear value (the white's centre = 1)")
plt.show()
