"""Reading a word: a DIGIT slides along a braille label strip and a classifier reads it.

``strip``: the label's geometry and the sliding frames; ``reader``: classify the frames and
aggregate them per cell; ``figure``: the frames at the cell centres; ``commands``: the
``read`` subcommand.
"""
