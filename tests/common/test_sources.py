"""pkm_common.sources: the one source of a topic a node acts on."""

from pkm_common.sources import Intrusion, SourceGate


def test_the_expected_source_alone_passes_and_any_other_publisher_is_named():
    gate = SourceGate("drives/state", "/pkm/sim_hw", "state_source")
    assert gate.check(["/pkm/sim_hw"]) is None
    assert gate.check([]) is None                                     # not discovered yet: nothing decided
    assert gate.check(["/pkm/sim_hw", "/rogue", "/rogue"]) == Intrusion(
        "/rogue publishes on drives/state (only /pkm/sim_hw may)", "/rogue")
    # an orphan of an earlier run has the source's very name: two publishers under it
    assert gate.check(["/pkm/sim_hw", "/pkm/sim_hw"]) == Intrusion(
        "a second /pkm/sim_hw publishes on drives/state (only /pkm/sim_hw may)", "a second /pkm/sim_hw")


def test_without_an_expected_source_the_one_publisher_at_the_first_message_is_it():
    gate = SourceGate("drives/state", "", "state_source")
    assert gate.check(["/a", "/b"]) is None                           # before the first message: undecided
    assert gate.connect(["/a"]) is None and gate.source == "/a"
    assert gate.check(["/a", "/b"]).sender == "/b"


def test_two_publishers_at_the_first_message_without_an_expected_source_are_refused_naming_the_parameter():
    two_named = SourceGate("drives/command", "", "command_source").connect(["/b", "/a"])
    assert two_named == Intrusion("2 publishers on drives/command (/a, /b): set command_source to the node name "
                                  "of its source", "/a, /b")
    one_not_named_yet = SourceGate("drives/command", "", "command_source")
    assert one_not_named_yet.connect(["/a"], matched=2).reason.startswith("2 publishers on drives/command")
    assert one_not_named_yet.source == ""


def test_more_publishers_matched_than_the_graph_names_yet_are_an_intruder_counted():
    """The matched event comes before discovery names the new publisher: counted now,
    named by a later check."""
    gate = SourceGate("drives/state", "/pkm/sim_hw", "state_source")
    assert gate.check(["/pkm/sim_hw"], matched=1) is None
    assert gate.check([], matched=1) is None                          # the source not discovered yet
    assert gate.check(["/pkm/sim_hw"], matched=2) == Intrusion("2 publishers on drives/state (only /pkm/sim_hw may)")
    assert gate.check([], matched=2).sender == ""
    assert gate.check(["/pkm/sim_hw", "/rogue"], matched=2).sender == "/rogue"     # named once known
    # with an expected source, a counted one at the first message too
    assert SourceGate("drives/state", "/pkm/sim_hw").connect(["/pkm/sim_hw"], matched=2).reason.startswith("2 ")


def test_a_command_is_taken_only_while_every_publisher_is_allowed():
    from pkm_common.sources import AllowedSenders, node_names
    allowed = node_names(" /pkm/panel, /pkm/bringup_monitor,,")
    assert allowed == {"/pkm/panel", "/pkm/bringup_monitor"}
    gate = AllowedSenders("controller/settings", allowed, "operator_sources")
    assert gate.check(["/pkm/panel"]) is None and gate.check([]) is None
    found = gate.check(["/pkm/panel", "/pkm/rogue", "/x/y", "/pkm/rogue"])
    assert found.sender == "/pkm/rogue, /x/y"
    assert found.reason == ("/pkm/rogue, /x/y publishes on controller/settings (only /pkm/bringup_monitor, "
                            "/pkm/panel may: operator_sources)")
    assert AllowedSenders("goal", node_names("")).check(["/anyone"]) is None       # a node run by hand: open
