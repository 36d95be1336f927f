"""Running receivers: the run's configuration from flags and files (:mod:`.config`), the live
daemon (:mod:`.daemon`), replay (:mod:`.replay`) and fleets (:mod:`.fleet`). Imports the stages
below (poses, device, receiver, sky), never the gap tool or the command line.
"""
