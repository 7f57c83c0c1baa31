"""The built-in gantry experiment (grasp and lift with an imperfect grasp) as a task package:
`task.py` declares it; its protocol, model element names, failure taxonomy, initial-state
records and the literal `mj_step` reference stepper live beside it."""
