"""Stand-in arms that are not PCC, for development and CI (issue 43): they write the recorded CSV
format that ``softpinn import`` reads (``docs/import.md``). ``_cosserat``: a Cosserat rod with a
heavy tip (PyElastica, the optional extra ``cosserat``), actuated through a lag and a dead time,
observed by a tip orientation sensor."""
