"""One-off studies behind defaults: the script that produced each number, kept with its results."""
