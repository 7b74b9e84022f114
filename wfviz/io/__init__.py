"""Input and output: clip readers (:mod:`.clip`), the frame and clip types (:mod:`.frames`),
safe output files (:mod:`.outputs`)."""
