import numpy as np
import tkujax

params = tkujax.ControllerParams.paper()               # the paper's T, γ, H_Sup, ε1, ε2, ...
pushes = tkujax.stack_pushes([tkujax.make_push(1.0, azimuth_deg=a) for a in (0, 90, 180, 270)])
series, outcomes = tkujax.simulate(pushes, enabled=np.ones(4), params=params)
print(outcomes.fell, outcomes.step_length_m)          # typed per-push outcomes (numpy)
