"""Stages shared by the trackers, one domain-named function module each: defects, imaging circle,
horizon, background suppression, noise, detection, camera motion (registration), centroids,
static clutter, and the front end that chains them for GEWC and fusion."""
