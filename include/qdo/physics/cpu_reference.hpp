// The CPU reference path: every physics stage in plain double precision (FFTW for FFTs,
// Eigen for small dense algebra). Slow and simple on purpose; the OpenCL kernels are tested
// against it. Conventions (Goodman): forward FFT e^{-i2π(fx x + fy y)}, inverse normalised by
// 1/M², diverging spherical wave exp(+ik r), DOE factor exp(+i k (n-1) H), Fresnel transfer
// function exp(-iπ λ z (fx² + fy²)) (the constant exp(ikz) dropped; the angular spectrum
// transfer function drops it too, so both are directly comparable).
//
// One header per stage, named after its kernel file (each stage's reference is
// src/physics/<stage>_reference.cpp): field, propagate, psf, camera (convolution), sensor, raw. This
// header includes them all.
#pragma once
#include "qdo/physics/camera_reference.hpp"
#include "qdo/physics/field_reference.hpp"
#include "qdo/physics/propagate_reference.hpp"
#include "qdo/physics/psf_reference.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/physics/sensor_reference.hpp"
