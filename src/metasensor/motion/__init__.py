"""Motion and turbulence correction of realigned views."""
