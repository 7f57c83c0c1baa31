"""The simulation: MuJoCo models loaded and run, episode by episode or in lockstep batches.

- `physics`: the physics-state layout, model loading, a compiled model's hash, what a healthy
  episode is.
- `engine`: the episodes of a task in batches (`mujoco.rollout`, or the closed loop).
- `closed_loop`: the lockstep closed loop (a policy once per control instant on a batch).
- `low_level`: a controller at the physics rate (`mj_step1`, the batched controller, `mj_step2`).
- `operational_space`, `controllers`: robosuite's OSC_POSE and GRIP; the LQR, encoder feedback,
  joint impedance.
- `actuation`: what a policy's output columns drive, applied at each control instant.
- `contacts`: the contacts MuJoCo makes (pairs, condim, friction, solref, solimp, margin, gap).
- `phases`: a rollout job's phases, timed.
- `simenv`: another MuJoCo version's environment (pins, build with uv, a job run in it).
- `resimulation`: verify's re-simulation, here or in such an environment.

Importing this package imports none of its modules (MuJoCo loads with the one that needs it).
"""
