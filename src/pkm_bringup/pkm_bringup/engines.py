"""What runs a scenario (no imports: pkm-run's argument parser, run_scenario and a
study's ``engine`` key read it): the direct engine (pkm_bringup.direct: the loops
without a transport) or the graph's nodes."""

ENGINES = ("direct", "graph")
