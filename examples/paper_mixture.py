"""The paper's mixture of 40 state-model adaptive Kalman filters (Wira, Urban & Gresser 2001).

One stream of frames (no time stamps: one row per frame, NaN for a missing frame), stepped
frame by frame, saved, resumed and run over the rest at once; then 50 streams at once.
"""
import numpy as np

from kalmix import MixturePredictor

rng = np.random.default_rng(0)
t = np.arange(300)
track = np.stack([200 + 80 * np.cos(0.05 * t), 150 + 60 * np.sin(0.03 * t)], axis=1)
measurements = track + rng.normal(0, 0.5, track.shape)      # pixels, with noise
measurements[100:105] = np.nan                               # NaN = a missing frame

predictor = MixturePredictor(n_experts=40, seed=0)           # 40 adaptive Kalman experts
for z in measurements[:200]:
    next_frame = predictor.step(z)                           # learn z, predict the next frame

print("3 frames ahead:", predictor.predict(horizon=3).round(2), "true:", track[202].round(2))
print("largest gating weights g_i (eq. 8):", np.sort(predictor.weights_)[::-1][:5].round(3))

predictor.save("predictor.npz")                              # the full state ...
resumed = MixturePredictor.load("predictor.npz")             # ... resumes bit for bit

result = resumed.run(measurements[200:])                     # a whole (T, p) array at once
errors = measurements[201:] - result.predictions[:-1]
print("one-step RMS error (px):", np.sqrt(np.nanmean(errors**2)).round(3))

# N streams at once: a (T, N, p) array, every stream with its own bank of experts
many = track[:, None, :] + rng.normal(0, 0.5, (300, 50, 2))
batch = MixturePredictor(n_experts=40, seed=0).run(many)
print("50 streams: predictions", batch.predictions.shape, "one-step RMS (px):",
      np.sqrt(np.mean((many[1:] - batch.predictions[:-1]) ** 2)).round(3))
