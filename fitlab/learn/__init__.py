"""SpongeCake's multiple-scattering lobe learned from the simulator: per material by a fit
(lobe.py, ``fitlab multiple-lobe``) and for every stack at once by the parameter-mapping network
(network.py, ``fitlab learn-lobe``). Above the simulator and the fitting; the model evaluates
the shipped network through fitlab/models/spongecake_network.py alone."""
