"""
Polar plots of the colour wheels
================================

The paper judges a correction by polar plots of the test target's colour wheels: each wheel's six segments at
their hue (angle) and saturation (radius), joined in a loop. Where the correction works, the loops of the corner
wheels lie on the centre wheel's; washed-out corners show as loops shrunk towards the middle.
"""

import matplotlib.pyplot as plt
import numpy as np

import picamcal
from picamcal.analysis.wheels import analyse
from picamcal.simulate import make_camera, simulate_references, simulate_target

camera = make_camera("imx219", size=(320, 240))
calibration = picamcal.calibrate(**simulate_references(camera, seed=1))
target, layout = simulate_target(camera, seed=2, noise=False)
images = {mode: picamcal.correct(target, calibration, mode=mode) for mode in ("uncorrected", "flat", "centre")}
analysis = analyse(images, layout)  # per mode: each wheel's segment hues and saturations, and the figures

for mode, result in analysis.items():
    summary = result["summary"]
    print(f"{mode:12} mean saturation of the other wheels / the centre's: {summary['mean_saturation_ratio']:.2f}")

# %%
# The centre wheel solid and black, the others dashed.

figure, axes = plt.subplots(1, 3, figsize=(12, 4.2), subplot_kw={"projection": "polar"}, layout="constrained")
for ax, (mode, result) in zip(axes, analysis.items(), strict=True):
    for name, wheel in result["wheels"].items():
        hue = np.radians(np.append(wheel["hue_deg"], wheel["hue_deg"][0]))
        saturation = np.append(wheel["saturation"], wheel["saturation"][0])
        style = {"color": "black", "linewidth": 2} if name == "centre" else {"linestyle": "--", "linewidth": 1}
        ax.plot(hue, saturation, marker="o", markersize=3, **style)
    ax.set_title(mode)
    ax.set_yticklabels([])
plt.show()
