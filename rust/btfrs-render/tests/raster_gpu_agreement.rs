//! The CPU rasteriser against a real Vulkan rasteriser (lavapipe, or whatever adapter wgpu finds):
//! the same meshes drawn with a minimal pipeline that writes the interpolated uv and the depth,
//! compared pixel by pixel: coverage must match exactly, uv and depth to f32 rounding.
//!
//! Like every GPU test of btfrs it fails, rather than skips, when no software Vulkan adapter is
//! installed (apt-get install mesa-vulkan-drivers). `BTFRS_RASTER_ADAPTER=gpu` compares against a
//! hardware adapter instead, whose sub-pixel snapping may round differently.

use btfrs_render::gpu::read_back_rgba;
use btfrs_render::raster::{rasterize, GBuffer};
use btfrs_render::scene::{Camera, Mesh};
use btfrs_render::{AdapterChoice, Gpu};

const SHADER: &str = r#"
struct U { vp: mat4x4<f32> };
@group(0) @binding(0) var<uniform> u: U;
struct VOut { @builtin(position) pos: vec4<f32>, @location(0) uv: vec2<f32> };
@vertex fn vs(@location(0) p: vec3<f32>, @location(1) uv: vec2<f32>) -> VOut {
    var o: VOut;
    o.pos = u.vp * vec4<f32>(p, 1.0);
    o.uv = uv;
    return o;
}
@fragment fn fs(i: VOut) -> @location(0) vec4<f32> {
    return vec4<f32>(i.uv, i.pos.z, 1.0);
}
"#;

/// lavapipe (a software Vulkan adapter) by default: the rules [`rasterize`] mirrors are its rules.
/// Hardware rasterisers may round snapped positions differently, so they are compared only on
/// request (`BTFRS_RASTER_ADAPTER=gpu`).
fn device() -> Gpu {
    let want_gpu = std::env::var("BTFRS_RASTER_ADAPTER").is_ok_and(|v| v == "gpu");
    Gpu::new(if want_gpu { &AdapterChoice::Gpu } else { &AdapterChoice::Cpu })
        .expect("no software Vulkan adapter: install lavapipe (apt-get install mesa-vulkan-drivers)")
}

/// Draws `mesh` and returns per pixel (u, v, depth, covered).
fn gpu_draw(dev: &Gpu, mesh: &Mesh, camera: &Camera, w: u32, h: u32) -> Vec<[f32; 4]> {
    use wgpu::util::DeviceExt;
    let d = &dev.device;
    let vp = camera.view_proj(w as f32 / h as f32);
    let module = d.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: None,
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let ubuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: bytemuck::cast_slice(&vp.to_cols_array()),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    let layout = d.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: None,
        entries: &[wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::VERTEX,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        }],
    });
    let bind_group = d.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &layout,
        entries: &[wgpu::BindGroupEntry { binding: 0, resource: ubuf.as_entire_binding() }],
    });
    let pipeline_layout = d.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: None,
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let attrs = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x2];
    let pipeline = d.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: None,
        layout: Some(&pipeline_layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs"),
            compilation_options: Default::default(),
            buffers: &[wgpu::VertexBufferLayout {
                array_stride: 20,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &attrs,
            }],
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: wgpu::TextureFormat::Depth32Float,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs"),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format: wgpu::TextureFormat::Rgba32Float,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    });
    let verts: Vec<f32> = (0..mesh.positions.len())
        .flat_map(|i| {
            let (p, t) = (mesh.positions[i], mesh.uvs[i]);
            [p[0], p[1], p[2], t[0], t[1]]
        })
        .collect();
    let vbuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: bytemuck::cast_slice(&verts),
        usage: wgpu::BufferUsages::VERTEX,
    });
    let ibuf = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: bytemuck::cast_slice(&mesh.indices),
        usage: wgpu::BufferUsages::INDEX,
    });
    let size = wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 };
    let texture = |format, usage| {
        d.create_texture(&wgpu::TextureDescriptor {
            label: None,
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    };
    let target = texture(
        wgpu::TextureFormat::Rgba32Float,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
    );
    let depth = texture(wgpu::TextureFormat::Depth32Float, wgpu::TextureUsages::RENDER_ATTACHMENT);
    let (tview, dview) = (target.create_view(&Default::default()), depth.create_view(&Default::default()));
    let mut enc = d.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: None,
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &tview,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &dview,
                depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Discard }),
                stencil_ops: None,
            }),
            ..Default::default()
        });
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.set_vertex_buffer(0, vbuf.slice(..));
        pass.set_index_buffer(ibuf.slice(..), wgpu::IndexFormat::Uint32);
        pass.draw_indexed(0..mesh.indices.len() as u32, 0, 0..1);
    }
    dev.queue.submit([enc.finish()]);
    read_back_rgba(dev, &target, w, h).expect("read-back")
}

struct Diff {
    coverage_mismatches: usize,
    covered: usize,
    max_uv: f32,
    max_depth: f32,
}

fn compare(dev: &Gpu, mesh: &Mesh, camera: &Camera, w: usize, h: usize) -> Diff {
    let gpu = gpu_draw(dev, mesh, camera, w as u32, h as u32);
    let cpu: GBuffer = rasterize(mesh, camera, w, h).unwrap();
    let mut d = Diff { coverage_mismatches: 0, covered: 0, max_uv: 0.0, max_depth: 0.0 };
    for (g, c) in gpu.iter().zip(&cpu.pixels) {
        match (g[3] > 0.5, c) {
            (true, Some(f)) => {
                d.covered += 1;
                d.max_uv = d.max_uv.max((g[0] - f.uv[0]).abs()).max((g[1] - f.uv[1]).abs());
                d.max_depth = d.max_depth.max((g[2] - f.depth).abs());
            }
            (false, None) => {}
            _ => d.coverage_mismatches += 1,
        }
    }
    d
}

fn fan_mesh() -> (Mesh, Camera) {
    // Triangles given in window coordinates of a 64 x 64 image seen by the camera above the origin,
    // with shared edges (horizontal, vertical, diagonal, generic) through pixel centres.
    let c = [32.5, 32.5];
    let rim = [
        [52.5, 32.5],
        [46.5, 46.5],
        [32.5, 52.5],
        [20.5, 50.5],
        [12.5, 32.5],
        [17.5, 15.5],
        [32.5, 12.5],
        [47.5, 21.0],
    ];
    let mut pts = vec![c];
    pts.extend_from_slice(&rim);
    let positions: Vec<[f32; 3]> =
        pts.iter().map(|p: &[f64; 2]| [((p[0] - 32.0) / 32.0) as f32, ((32.0 - p[1]) / 32.0) as f32, 0.0]).collect();
    let uvs: Vec<[f32; 2]> = positions.iter().map(|p| [p[0], p[1]]).collect();
    let faces: Vec<[u32; 3]> = (0..8u32).map(|k| [0, 1 + k, 1 + (k + 1) % 8]).collect();
    let mesh = Mesh::from_arrays(&positions, &uvs, &faces, None).unwrap();
    (mesh, Camera::look_at([0.0, 0.0, 1.0], [0.0; 3], 90.0).unwrap())
}

/// A soup of overlapping random triangles around the camera, some crossing the near plane or
/// leaving the frustum, for depth ordering and clipping.
fn soup() -> (Mesh, Camera) {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut positions, mut uvs, mut faces) = (Vec::new(), Vec::new(), Vec::new());
    for t in 0..300u32 {
        let centre = [rnd() * 6.0 - 3.0, rnd() * 6.0 - 1.0, rnd() * 4.0 - 2.0];
        for _ in 0..3 {
            positions.push([0, 1, 2].map(|k| (centre[k] + rnd() * 3.0 - 1.5) as f32));
            uvs.push([rnd() as f32, rnd() as f32]);
        }
        faces.push([3 * t, 3 * t + 1, 3 * t + 2]);
    }
    let mesh = Mesh::from_arrays(&positions, &uvs, &faces, None).unwrap();
    (mesh, Camera::look_at([0.0, -2.0, 0.3], [0.2, 1.0, 0.0], 70.0).unwrap())
}

#[test]
fn cpu_raster_matches_the_vulkan_rasteriser() {
    let dev = device();
    eprintln!("adapter: {}", dev.describe());
    let floor = |z: f32, half: f32, near: f32| {
        let p = [[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]];
        let uv = p.map(|q| [q[0] / (2.0 * half) + 0.5, q[1] / (2.0 * half) + 0.5]);
        let mesh = Mesh::from_arrays(&p, &uv, &[[0, 1, 2], [0, 2, 3]], None).unwrap();
        let cam = Camera { near, ..Camera::look_at([0.0; 3], [0.0, 1.0, 0.0], 90.0).unwrap() };
        (mesh, cam)
    };
    let top = Camera::look_at([0.0, 0.0, 1.0], [0.0; 3], 90.0).unwrap();
    let scenes: Vec<(&str, Mesh, Camera, usize, usize)> = vec![
        (
            "sphere",
            Mesh::sphere(1.0, 64, 32).unwrap(),
            Camera::look_at([2.2, -3.1, 1.4], [0.0; 3], 40.0).unwrap(),
            256,
            192,
        ),
        (
            "sphere close",
            Mesh::sphere(1.0, 64, 32).unwrap(),
            Camera::look_at([0.3, -1.6, 0.4], [0.0; 3], 90.0).unwrap(),
            200,
            160,
        ),
        (
            "cylinder",
            Mesh::cylinder(0.8, 2.0, 48).unwrap(),
            Camera::look_at([1.0, -3.0, 2.5], [0.0; 3], 50.0).unwrap(),
            160,
            160,
        ),
        ("plane on centres", Mesh::plane(0.65625), top, 64, 64),
        ("plane large", Mesh::plane(100.0), top, 33, 17),
        ("fan", fan_mesh().0, fan_mesh().1, 64, 64),
        ("floor behind eye", floor(-1.0, 50.0, 0.01).0, floor(-1.0, 50.0, 0.01).1, 100, 100),
        ("floor near cut", floor(-0.5, 40.0, 1.0).0, floor(-0.5, 40.0, 1.0).1, 100, 100),
        ("soup", soup().0, soup().1, 240, 180),
    ];
    let mut failures = Vec::new();
    for (name, mesh, cam, w, h) in &scenes {
        let d = compare(&dev, mesh, cam, *w, *h);
        eprintln!(
            "{name:>16}: {} covered, {} coverage mismatches, max |uv| diff {:.2e}, max depth diff {:.2e}",
            d.covered, d.coverage_mismatches, d.max_uv, d.max_depth
        );
        if d.coverage_mismatches > 0 || d.max_uv > 2e-4 || d.max_depth > 1e-5 {
            failures.push(*name);
        }
    }
    assert!(failures.is_empty(), "CPU and GPU rasterisers disagree on {failures:?}");
}
