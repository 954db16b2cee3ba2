"""The checks of values every command and the recipe loader build on, before any work.

A careless or hostile input must be refused in one line naming the argument, key or file,
before a stage runs or a byte is written: sizes and counts are bounded and checked against
a memory estimate (:mod:`.limits`), YAML is read by a loader that refuses alias bombs and
duplicate keys (:mod:`.safe_yaml`), images are checked from their header before decoding
(:mod:`.images`), output locations are checked and locked (:mod:`.outputs`), and argument
values follow a kind of rule (:mod:`.args`). Nothing here knows the domain: which command
argument follows which rule is ``tactile_bench.cli_args``, the recipe rules
``tactile_bench.pipeline.recipe_rules``.
"""
