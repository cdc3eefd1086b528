"""Renders one scene of brickray's `vtk` bench suite with VTK's volume mappers.

Run by `brickray-bench vtk` (crates/bench/src/pareto/vtk.rs), which writes the
scene as JSON: the raw volume and its placement in brickray's world (voxel
centres, so VTK's point samples fall where brickray's voxel values lie), the
transfer function as points on the raw values, the camera, the shading and
the sample steps. For each mapper (the CPU fixed-point ray caster and the
OpenGL GPU ray caster) and each step, one untimed render absorbs set-up
(gradients, textures), then `frames` renders are timed, each until the
window has finished (`Render` + `WaitForCompletion`). The last image is
written as RGBA8, top row first. The results are one JSON line on stdout.

Needs `pip install vtk`; renders offscreen (EGL or an X display).
"""

import json
import sys
import time

import numpy as np
import vtk
from vtk.util import numpy_support

DTYPES = {"u8": np.uint8, "u16": np.uint16, "i16": np.int16, "f32": np.float32}


def volume(scene):
    data = np.fromfile(scene["raw"], dtype=np.dtype(DTYPES[scene["dtype"]]).newbyteorder("<"))
    data = data.astype(DTYPES[scene["dtype"]])
    image = vtk.vtkImageData()
    image.SetDimensions(*scene["dims"])
    image.SetSpacing(*scene["spacing"])
    image.SetOrigin(*scene["origin"])
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(data, deep=True))
    return image


def prop(scene):
    colour = vtk.vtkColorTransferFunction()
    opacity = vtk.vtkPiecewiseFunction()
    for v, r, g, b, a in scene["tf"]:
        colour.AddRGBPoint(v, r, g, b)
        opacity.AddPoint(v, a)
    p = vtk.vtkVolumeProperty()
    p.SetColor(colour)
    p.SetScalarOpacity(opacity)
    p.SetScalarOpacityUnitDistance(scene["opacity_unit"])
    p.SetInterpolationTypeToLinear()
    if scene["shade"]:
        s = scene["shading"]
        p.ShadeOn()
        p.SetAmbient(s["ambient"])
        p.SetDiffuse(s["diffuse"])
        p.SetSpecular(s["specular"])
        p.SetSpecularPower(s["shininess"])
    else:
        p.ShadeOff()
    return p


def mapper(kind, scene, image):
    if kind == "cpu":
        m = vtk.vtkFixedPointVolumeRayCastMapper()
        m.SetImageSampleDistance(1.0)
        m.SetMinimumImageSampleDistance(1.0)
        m.SetMaximumImageSampleDistance(1.0)
        m.SetLockSampleDistanceToInputSpacing(0)
    else:
        m = vtk.vtkGPUVolumeRayCastMapper()
        m.SetUseJittering(0)
    m.SetAutoAdjustSampleDistances(0)
    m.SetInputData(image)
    if scene["mode"] == "mip":
        m.SetBlendModeToMaximumIntensity()
    else:
        m.SetBlendModeToComposite()
    return m


def window(scene, vol):
    r = vtk.vtkRenderer()
    r.SetBackground(0.0, 0.0, 0.0)
    r.AddVolume(vol)
    cam = r.GetActiveCamera()
    cam.SetPosition(*scene["eye"])
    cam.SetFocalPoint(*scene["target"])
    cam.SetViewUp(*scene["up"])
    cam.SetViewAngle(scene["fov_y_deg"])
    r.ResetCameraClippingRange()
    w = vtk.vtkRenderWindow()
    w.SetOffScreenRendering(1)
    w.SetMultiSamples(0)
    w.AddRenderer(r)
    w.SetSize(scene["size"], scene["size"])
    return w


def render(w):
    t = time.perf_counter()
    w.Render()
    w.WaitForCompletion()
    return (time.perf_counter() - t) * 1000.0


def read_rgba(w):
    grab = vtk.vtkWindowToImageFilter()
    grab.SetInput(w)
    grab.SetInputBufferTypeToRGB()
    grab.ReadFrontBufferOff()
    grab.Update()
    out = grab.GetOutput()
    wd, ht, _ = out.GetDimensions()
    rgb = numpy_support.vtk_to_numpy(out.GetPointData().GetScalars()).reshape(ht, wd, 3)
    rgba = np.full((ht, wd, 4), 255, dtype=np.uint8)
    rgba[:, :, :3] = np.flipud(rgb)
    return rgba


def main():
    scene = json.load(open(sys.argv[1]))
    image = volume(scene)
    results = []
    for kind in scene["mappers"]:
        m = mapper(kind, scene, image)
        vol = vtk.vtkVolume()
        vol.SetMapper(m)
        vol.SetProperty(prop(scene))
        w = window(scene, vol)
        setup_ms = None
        for step in scene["steps"]:
            m.SetSampleDistance(step * scene["opacity_unit"])
            first = render(w)
            if setup_ms is None:
                setup_ms = first
            ms = [render(w) for _ in range(scene["frames"])]
            path = "%s_%s_%g.rgba" % (scene["out_prefix"], kind, step)
            read_rgba(w).tofile(path)
            results.append(
                {"mapper": kind, "step": step, "ms": ms, "first_ms": first, "image": path}
            )
        results.append({"mapper": kind, "setup_ms": setup_ms})
        w.Finalize()
    print(json.dumps({"vtk": vtk.vtkVersion.GetVTKVersion(), "results": results}))


if __name__ == "__main__":
    main()
