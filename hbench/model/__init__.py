"""The parts of a closed loop: plants, controllers, valve nonlinearities, noise models and reference
signals, each vectorised over Monte Carlo runs and registered by name."""
