//! `montecarlo`: stochastic light transport through volrad's piecewise-constant media.
