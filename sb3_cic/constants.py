"""URLB constants: the expert scores behind the normalised score, and the published results."""

from __future__ import annotations

#: expert returns of the 12 URLB tasks (normalised score = return / expert)
EXPERT_SCORES: dict[str, float] = {
    "walker_stand": 984.0,
    "walker_walk": 971.0,
    "walker_run": 796.0,
    "walker_flip": 799.0,
    "quadruped_walk": 866.0,
    "quadruped_run": 888.0,
    "quadruped_stand": 920.0,
    "quadruped_jump": 888.0,
    "jaco_reach_top_left": 191.0,
    "jaco_reach_top_right": 223.0,
    "jaco_reach_bottom_left": 193.0,
    "jaco_reach_bottom_right": 203.0,
}

#: published state-based URLB IQM of normalised scores (2M pre-training, 100k fine-tuning)
PUBLISHED_IQM: dict[str, float] = {
    "CIC": 0.77,
    "APT": 0.65,
    "ProtoRL": 0.65,
    "RND": 0.61,
    "Disagreement": 0.51,
    "APS": 0.43,
    "ICM": 0.41,
    "DIAYN": 0.40,
    "SMM": 0.25,
}


def normalized_score(task: str, episode_return: float) -> float:
    """URLB normalised score: ``return / expert score`` (no random baseline subtracted).

    :param task: URLB task name, e.g. ``walker_flip``
    :param episode_return: mean episode return
    """
    if task not in EXPERT_SCORES:
        raise ValueError(f"no expert score for task {task!r}; known: {sorted(EXPERT_SCORES)}")
    return float(episode_return) / EXPERT_SCORES[task]
