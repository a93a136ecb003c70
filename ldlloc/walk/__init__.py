"""Walks: a sequence of panoramas (a capture tour, a 360 video) localized as one (docs/commands.md#walks-and-videos---walk---video).

:mod:`.hypotheses` (each frame's poses over every map), :mod:`.motion` (what a walking person can
do between two frames), :mod:`.viterbi` (the most likely path, and each frame's margin),
:mod:`.localize` (global localization, tracking, the path, the frames the walk decided),
:mod:`.order` (the order of a folder of photos), :mod:`.options` (the CLI checks), :mod:`.run`
(results records and runs).
"""
