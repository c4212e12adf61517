"""Forming: rigid tool surfaces, contact with friction, the force-controlled blank holder, the
forming process and its reports, and the kinematic (fishnet) drape as a force-free check."""
