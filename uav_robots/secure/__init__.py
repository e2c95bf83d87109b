"""Mutual TLS and access control: a fleet's CA, certificates and Zenoh configs (`uav-robots secure init`)."""
