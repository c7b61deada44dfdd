"""The recipe of ``unwrap_single(method="learned")``'s weights: the edge network (:mod:`.train`, on the scenes of
:mod:`.procedural` and the CC0/BSD development scenes), its level head (:mod:`.levels`) and a selection set of six other
CC0 scenes (:mod:`.fetch_selection_scenes`). README.md beside it has the commands."""
