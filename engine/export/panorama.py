"""Panoramic cameras: a Blender camera of type PANO -> kernels.Camera.panorama_type and .panorama.

What Cycles' Blender layer makes of the settings (intern/cycles/blender/camera.cpp): the projection's
parameters as they are, the central cylindrical height range divided by its radius in the kernel, and
for the equisolid and polynomial fisheyes the sensor fitted to the frame: the fit axis (AUTO: the wider
side, counting the pixel aspect) takes the sensor width (VERTICAL fit: the sensor height), the other
side follows the frame's aspect. The lens shift, clipping and depth of field are kernels.Camera fields,
read by export_camera as for any camera.
"""
from __future__ import annotations

from ...kernels.panorama import PANORAMA_PARAMS

# Parameters that are Blender properties of the same name.
_SAME_NAME = ("latitude_min", "latitude_max", "longitude_min", "longitude_max", "fisheye_fov", "fisheye_lens",
              "fisheye_polynomial_k0", "fisheye_polynomial_k1", "fisheye_polynomial_k2", "fisheye_polynomial_k3",
              "fisheye_polynomial_k4", "central_cylindrical_range_u_min", "central_cylindrical_range_u_max",
              "central_cylindrical_range_v_min", "central_cylindrical_range_v_max", "central_cylindrical_radius")


def export_panorama(camera_ob, scene, width: int, height: int, warnings: list[str]) -> tuple[str, dict]:
    """(panorama_type, params) for the evaluated camera object camera_ob of type PANO; width, height: the
    full frame in pixels. What is not rendered as Cycles renders it goes to warnings, one line each."""
    cam = camera_ob.data
    panorama_type = cam.panorama_type
    sensor_width, sensor_height = fitted_sensor(cam, scene.render, width, height)
    values = {name: float(getattr(cam, name)) for name in _SAME_NAME}
    values.update(sensor_width=sensor_width, sensor_height=sensor_height)
    if scene.render.use_multiview:
        warnings.append(f"Camera '{camera_ob.name}': stereo views of a panoramic camera are rendered from its "
                        f"centre, without spherical stereo")
    return panorama_type, {name: values[name] for name in PANORAMA_PARAMS[panorama_type]}


def fitted_sensor(cam, render, width: int, height: int) -> tuple[float, float]:
    """(sensor_width, sensor_height) in mm of the sensor fitted to the frame, as Cycles fits it for the
    equisolid and polynomial fisheyes."""
    fit_x = width * render.pixel_aspect_x
    fit_y = height * render.pixel_aspect_y
    if cam.sensor_fit == "VERTICAL":
        horizontal, size = False, cam.sensor_height
    else:
        horizontal, size = cam.sensor_fit == "HORIZONTAL" or fit_x > fit_y, cam.sensor_width
    if horizontal:
        return float(size), float(size * fit_y / fit_x)
    return float(size * fit_x / fit_y), float(size)
