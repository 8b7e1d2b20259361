"""The functional core under MixturePredictor: pure functions on batched arrays.

``step(params, state, z)`` returns a new state and the outputs; nothing is modified in place,
so a state can be kept, copied or stepped again from any point. ``run_core`` runs a whole
``(T, N, p)`` array (compiled with numba when it is installed) and resumes from any state.
"""
import numpy as np

from kalmix import make_params
from kalmix.core import init_state, run_core, step

rng = np.random.default_rng(1)
start = rng.normal(300, 50, size=(1000, 3))                      # 1000 targets in 3-D
velocity = rng.normal(0, 2, size=(1000, 3))
frames = start + np.arange(100)[:, None, None] * velocity + rng.normal(0, 1, size=(100, 1000, 3))

params = make_params(measurement_dim=3, n_experts=40, seed=0)   # validated, seeded bank recipe
state = init_state(params, n_targets=1000)
for z in frames[:3]:                                             # one frame of all targets at a time
    state, out = step(params, state, z)                          # out.prediction: (1000, 3)

result = run_core(params, frames[3:], state)                     # the other 97 frames at once
errors = frames[51:] - result.predictions[47:-1]                 # predictions[t] forecasts frame t + 1
print("predictions:", result.predictions.shape, "weights:", result.state.weights.shape)
print("one-step RMS error over frames 51-99:", np.sqrt(np.mean(errors ** 2)).round(3))
