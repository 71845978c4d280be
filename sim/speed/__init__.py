"""Speed measurements of the stack, one command with subcommands (``scripts/speed.py NAME [options]``,
``sim.speed.cli``). Each prints medians and 95th percentiles with the machine's load average and
asserts nothing; ``--quick`` runs any of them in seconds (a smoke test: its numbers mean nothing).

``SUBCOMMANDS`` names each one's module and says what it measures; their shared timing code is in
``sim.speed.timing``, and the copies of the control loop's step that ``loop`` times stage by stage
are in ``sim.speed.instrumented`` (the one place that reaches into the loop's internals). The top
group of ``sim``: it may import every other (pyproject.toml's import contracts).
"""

#: subcommand -> (its module, what it measures)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "field": ("sim.speed.field", "one single-point call field(x) per learner, the control loop's path"),
    "pose": ("sim.speed.pose", "one pose field at one point per learner, pose in and twist out"),
    "node": ("sim.speed.node", "the NODE learner's training time and accuracy on torchdiffeq's spiral"),
    "ik": ("sim.speed.ik", "the differential IK back-ends, dls against pink, on the same rollout"),
    "loop": ("sim.speed.loop", "one closed-loop control step against a bare mj_step; actuations, planes"),
    "obstacles": ("sim.speed.obstacles", "obstacle avoidance and moving goals in task space: cost and results"),
    "arm-clearance": ("sim.speed.arm_clearance", "what whole-arm clearance costs per control step on the Panda"),
    "render": ("sim.speed.render", "video frames per second of sim.media.render (GL, overlays, H.264)"),
    "tasks": ("sim.speed.tasks", "the control step with a task's objects against the empty scene, net of physics"),
}
