"""The example scenes (``*.toml``), installed as package data so that ``wavlight scenes`` lists
them and ``wavlight render --demo NAME`` renders one (:mod:`wavlight.demos`). Each needs only
what is built in or shipped (``data:`` assets of :mod:`wavlight.data`)."""
