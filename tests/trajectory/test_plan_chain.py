"""The planner's pose follows only what the controller accepted (plan_chain)."""

import json

from pkm_trajectory.plan_chain import PlanChain, trajectory_verdict

HOME = [1.0, -0.4, 0.7]


def event(kind: str, ok: bool) -> str:
    return json.dumps({"kind": kind, "ok": ok, "after_ns": 5, "message": "" if ok else "refused"})


def test_a_refused_goal_leaves_the_start_where_the_machine_is():
    chain = PlanChain(HOME)
    far = [1.0, -0.3, 0.7]
    chain.published(far)
    assert chain.start() == far                   # chained while the verdict is pending
    assert chain.verdict(*trajectory_verdict(event("trajectory", False)))
    assert chain.start() == HOME                  # before: the planner moved to `far` all the same
    chain.published([1.0, -0.401, 0.7])
    assert chain.verdict(True) and chain.start() == [1.0, -0.401, 0.7]


def test_plans_chained_on_a_refused_one_are_dropped_with_it():
    chain = PlanChain(HOME)
    a, b, c = [1.01, -0.4, 0.7], [1.02, -0.4, 0.7], [1.03, -0.4, 0.7]
    for end in (a, b, c):
        chain.published(end)
    assert chain.verdict(True) and chain.start() == c
    assert chain.verdict(False) and chain.start() == a          # b refused: c started from it
    assert not chain.verdict(False) and chain.start() == a      # c's own verdict: nothing pending


def test_only_trajectory_verdicts_count():
    assert trajectory_verdict(event("feed_override", True)) is None
    assert trajectory_verdict("not json") is None and trajectory_verdict("[1]") is None
    assert trajectory_verdict(event("trajectory", True)) == (True, None)
    chain = PlanChain(HOME)
    assert not chain.verdict(True) and chain.start() == HOME     # a verdict on nothing of ours


def test_a_verdict_names_its_trajectory_and_those_never_judged_are_dropped():
    """The trajectory topic keeps the last message only: two plans published within a
    controller cycle, the first is never read, never judged. Matched by order, the
    verdict on the second went to the first (and a refusal cleared the second)."""
    chain = PlanChain(HOME)
    first, second = [1.01, -0.4, 0.7], [1.02, -0.4, 0.7]
    chain.published(first, 100)
    chain.published(second, 200)
    text = json.dumps({"kind": "trajectory", "ok": True, "stamp_ns": 200, "after_ns": 5, "message": ""})
    assert chain.verdict(*trajectory_verdict(text)) and chain.start() == second and not chain.pending
    assert chain.accepted == second
    chain.published([1.03, -0.4, 0.7], 300)
    assert not chain.verdict(False, 999) and chain.start() == [1.03, -0.4, 0.7]     # not ours: ignored
    assert chain.verdict(False, 300) and chain.start() == second
