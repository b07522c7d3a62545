"""Tasks of the environments: goal sampling, reward terms, success and termination.

One module per task. A task knows nothing of PyBullet: it draws its goals
(and its arena) from the env's generator, scores ground-truth states handed to
it by the env and says when an episode ends. The env composes robot + task +
observation pipeline.
"""
