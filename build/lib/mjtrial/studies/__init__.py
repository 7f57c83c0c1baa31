"""Studies beyond the built-in experiment: simulator sensitivity and a dose-response sweep."""
