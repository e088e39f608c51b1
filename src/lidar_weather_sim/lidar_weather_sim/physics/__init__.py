"""Physical atmosphere coefficients (no ROS, no simulator import): drop-size distributions
(:mod:`.dsd`), Mie efficiencies (:mod:`.mie`), extinction and backscatter from both
(:mod:`.coefficients`) and the biaxial overlap of a sender and a receiver (:mod:`.overlap`)."""
