"""
Before and after: the four correction modes
===========================================

A simulated Camera Module v2 (IMX219) behind normally incident optics photographs the colour-wheel test target.
The bare sensor darkens and tints the corners (vignetting) and washes their colours out (crosstalk between
neighbouring pixels). Five reference images calibrate it; each correction mode then removes more of the error:
``flat`` the vignetting and colour cast, ``centre`` also the crosstalk, to the colours of the sensor's centre,
``pure`` to pure primaries.
"""

import matplotlib.pyplot as plt

import picamcal
from picamcal.analysis.metrics import encode_srgb, wheel_figures
from picamcal.simulate import make_camera, simulate_references, simulate_target

camera = make_camera("imx219", size=(320, 240))
references = simulate_references(camera, seed=1)  # white, red, green, blue, black: RawImages
calibration = picamcal.calibrate(**references)
target, layout = simulate_target(camera, seed=2)  # the colour-wheel target, and where its wheels are

# %%
# Correct the target in every mode, and compare each corner wheel with the centre wheel (CIEDE2000: about 1 is
# a just-noticeable difference).

modes = ["uncorrected", "flat", "centre", "pure"]
corrected = {mode: picamcal.correct(target, calibration, mode=mode) for mode in modes}
for mode, rgb in corrected.items():
    figures = wheel_figures(rgb, layout)
    print(f"{mode:12} corner ΔE2000 max {figures['max_delta_e']:5.2f}  mean {figures['mean_delta_e']:5.2f}")

figure, axes = plt.subplots(1, 4, figsize=(12, 2.6), layout="constrained")
for ax, (mode, rgb) in zip(axes, corrected.items(), strict=True):
    ax.imshow(encode_srgb(rgb))
    ax.set_title(mode)
    ax.set_axis_off()
plt.show()
