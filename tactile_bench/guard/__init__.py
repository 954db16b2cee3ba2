"""The validation layer every command and the recipe loader go through, before any work.

A careless or hostile input must be refused in one line naming the argument, key or file,
before a stage runs or a byte is written: sizes and counts are bounded and checked against
a memory estimate (:mod:`.limits`), YAML is read by a loader that refuses alias bombs and
duplicate keys (:mod:`.safe_yaml`), images are checked from their header before decoding
(:mod:`.images`), output locations are checked and locked (:mod:`.outputs`), and command
arguments and recipes are checked against declared rules (:mod:`.args`, :mod:`.recipes`).
"""
