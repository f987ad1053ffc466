"""Robot programs compensated with a calibration bundle: KUKA KRL (:mod:`.krl`) and ABB RAPID (:mod:`.rapid`)
readers and writers, and the filter (:mod:`.filter`)."""
