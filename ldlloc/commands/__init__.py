"""What the commands of ``ldlloc`` (:mod:`ldlloc.cli`) do once their options are parsed: one module
per command (:mod:`.localize`, :mod:`.run`, :mod:`.report`), the localization options they share
(:mod:`.options`) and the tables and lines a run prints (:mod:`.show`). The CLI loads them on first
use, so ``ldlloc --help`` loads none of them."""
