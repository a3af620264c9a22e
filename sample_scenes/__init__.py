"""Synthetic capture studio (bpy) and the committed default sample scene."""
