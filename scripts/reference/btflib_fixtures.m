% Reference fixtures for the UBO2014 DFMF `.btf` reader, made with btflib.
%
% Writes small DFMF files with btflib's own writer (btf('DFMF', meta, data)
% followed by btf.write, i.e. btflib's write_ubo_dfmf), reads each file back
% with btflib's reader (btf(file)) and stores every (view, light) image that
% btflib's decoder (btf.decode_texture with integer indices) returns, so that
% btfrs can be checked against the reference library without Octave.
%
% Made with:
%   GNU Octave 7.3.0 (Debian 12 package octave 7.3.0-2)
%   btflib https://github.com/cgbonn/btflib
%          commit a9645d520417995603d7e16f38150f599d011e2e (2019-12-03)
%
% Usage (see btflib_fixtures.sh, which installs Octave and fetches btflib):
%   octave --no-gui -q --eval "addpath('scripts/reference'); ...
%       btflib_fixtures('/path/to/btflib', 'tests/fixtures/ubo2014')"
%
% No btflib code is copied into this repository. At run time the script
% prepares a scratch directory (outside the repository) so that btflib runs in
% Octave; each step there is a workaround for an Octave difference, not a
% change to what btflib computes:
%   1. btflib's matlab/ folder is copied to the scratch directory and the files
%      of @btf/private/ are also placed directly in @btf/. btflib calls its
%      private functions with method syntax (obj.create_ubo_dfmf(...),
%      obj.decode_dfmf_texture(...), obj.undecorrelate(...)); MATLAB accepts
%      that, Octave only finds them as methods of the class folder. The
%      private/ copies stay where they are for plain calls (read_ubo_dfmf ...).
%   2. A copy of Octave's own inputParser.m without the check "can't have a
%      Required argument after Optional, Parameter, or Switch": btf's
%      constructor adds Required arguments after Parameters, which MATLAB
%      allows. Octave's parse handles that order unchanged.
%   3. knnsearch (Octave statistics package, not installed): brute-force
%      nearest neighbour with K = 1. btflib only uses it in
%      utils.add_bottom_ring for the direction interpolation set-up.
%   4. delaunayTriangulation (not in Octave): a stand-in struct. btflib builds
%      it in init_dirs for interpolating arbitrary directions; decoding by
%      integer light/view indices (all this script does) never uses it.
%   5. halfprecision (btflib's bundled MEX, thirdparty/half_precision) is
%      compiled with mkoctfile --mex into the scratch directory.
%   6. Files are read back from a path without dots: btf.read calls
%      which(file_name), and Octave's which() takes "dir/name.btf" for a
%      package name and fails.

function btflib_fixtures(btflib_dir, out_dir)
    if nargin < 2
        error('usage: btflib_fixtures(btflib_dir, out_dir)');
    end
    btflib_dir = make_absolute(btflib_dir);
    out_dir = make_absolute(out_dir);
    if ~exist(out_dir, 'dir')
        mkdir(out_dir);
    end

    % btflib's +utils/sizeof.m and the inputParser stand-in shadow built-ins
    warning('off', 'Octave:shadowed-function');
    scratch = prepare_scratch(btflib_dir);
    cleanup = onCleanup(@() remove_dir(scratch));

    versions.octave = OCTAVE_VERSION;
    versions.btflib_commit = btflib_commit(btflib_dir);

    % angular sampling: distinct polar angles and azimuths (degrees)
    light_theta = [5, 25, 40, 55, 70];
    light_phi = [0, 75, 150, 215, 290];
    view_theta = [10, 35, 60];
    view_phi = [30, 140, 260];
    % a non-square texture: 7 columns (width), 5 rows (height)
    w = 7;
    h = 5;

    scale = [2, 0.5, 1.5];
    pca_matrix = [0.6, 0.3, 0.2; 0.5, -0.1, -0.4; 0.4, -0.35, 0.25];
    pca_mean = [0.05, 0.1, 0.15];

    % name, colour model, cosine flag, rgb scale, components per channel,
    % singular values given?, channel scales (model space)
    specs = {
        'rgb_cos0',          0,  false, [1, 1, 1], [3, 2, 2], false, [1, 1, 1]
        'rgb_cos1',          0,  true,  [1, 1, 1], [3, 2, 2], false, [1, 1, 1]
        'rgb_cos0_scale',    0,  false, scale,     [3, 2, 2], false, [1, 1, 1]
        'rgb_cos1_scale',    0,  true,  scale,     [3, 2, 2], false, [1, 1, 1]
        'rgb_svals',         0,  false, [1, 1, 1], [3, 3, 3], true,  [1, 1, 1]
        'yuv',               1,  false, [1, 1, 1], [3, 2, 2], false, [1, 0.15, -0.15]
        'yuv_cos1_scale',    1,  true,  scale,     [3, 2, 2], false, [1, 0.15, -0.15]
        'pca',               3,  false, [1, 1, 1], [3, 2, 2], false, [1, 0.3, -0.2]
        'ycocg',             4,  false, [1, 1, 1], [3, 2, 2], false, [1, 0.15, -0.1]
        'ylog_uv',           9,  false, [1, 1, 1], [3, 2, 2], false, [1, 0.15, -0.15]
        'ylog_ulog_vlog',    10, false, [1, 1, 1], [3, 2, 2], false, [1, 8, -8]
        'ylog_udivy_vdivy',  11, false, [1, 1, 1], [3, 2, 2], false, [1, 0.15, -0.15]
        'logrgb',            12, false, [1, 1, 1], [3, 2, 2], false, [-0.5, 0.4, 0.7]
    };

    tmp_read = fullfile(scratch, 'readback');
    for si = 1 : size(specs, 1)
        [name, model, cosine_flag, rgb_scale, ncomp, with_s, ch_scale] = specs{si, :};

        [L, V] = directions(light_theta, light_phi, view_theta, view_phi);
        nL = size(L, 1);
        nV = size(V, 1);

        meta = struct();
        meta.width = w;
        meta.height = h;
        meta.num_lights = nL;
        meta.num_views = nV;
        meta.light_dirs = L;
        meta.view_dirs = V;
        meta.cosine_flag = cosine_flag;
        meta.rgb_scale_factor = rgb_scale;
        meta.ppmm = 12.5;
        meta.measurement_setup = 'btfrs reference fixture';
        meta.image_sensor = 'closed-form data';
        meta.light_source = 'none';
        meta.xml = sprintf('<fixture name="%s"/>', name);
        meta.color_model = model;
        if model == 3
            meta.color_mean = pca_mean;
            meta.color_transformation_matrix = pca_matrix;
        end

        data = struct();
        [data.U, data.SxV] = factors(L, V, w, h, ncomp, ch_scale);
        if with_s
            data.S = repmat({[4; 2; 0.5]}, 3, 1);
        end

        % btflib's writer: btf object from memory, then btf.write
        b = btf('DFMF', meta, data);
        btf_file = fullfile(out_dir, [name, '.btf']);
        b.write(btf_file);
        clear b;

        decode_and_describe(name, btf_file, out_dir, tmp_read, versions, ...
            light_theta, light_phi, view_theta, view_phi, ch_scale, '');
    end

    % Not written by btflib's writer (it always writes half floats): the
    % payload of rgb_cos1.btf re-encoded with float / double / half scalars
    % (channel R, G, B), header bytes unchanged; decoded by btflib's reader,
    % which reads scalar sizes 2, 4 and 8.
    name = 'rgb_cos1_f32_f64_f16';
    btf_file = fullfile(out_dir, [name, '.btf']);
    transcode(fullfile(out_dir, 'rgb_cos1.btf'), btf_file, [4, 8, 2]);
    decode_and_describe(name, btf_file, out_dir, tmp_read, versions, ...
        light_theta, light_phi, view_theta, view_phi, [1, 1, 1], ...
        ['payload of rgb_cos1.btf (written by btflib) re-encoded by ' ...
         'btflib_fixtures.m with scalar sizes 4, 8, 2 for channels 1, 2, 3; ' ...
         'decoded by btflib']);
end

function decode_and_describe(name, btf_file, out_dir, tmp_read, versions, ...
                             light_theta, light_phi, view_theta, view_phi, ch_scale, origin)
    % btflib's reader and decoder
    copyfile(btf_file, tmp_read);
    r = btf(tmp_read);
    delete(tmp_read);

    decoded = zeros(3, r.meta.width, r.meta.height, r.meta.nL, r.meta.nV, 'single');
    for v = 1 : r.meta.nV
        for l = 1 : r.meta.nL
            img = r.decode_texture(int32(l), int32(v)); % h x w x 3
            assert(isequal(size(img), [r.meta.height, r.meta.width, 3]));
            decoded(:, :, :, l, v) = permute(single(img), [3, 2, 1]);
        end
    end
    % column-major [channel, col, row, light, view] is row-major
    % [view][light][row][col][channel]
    fid = fopen(fullfile(out_dir, [name, '.btflib.f32']), 'w', 'ieee-le');
    fwrite(fid, decoded, 'single');
    fclose(fid);

    write_json(fullfile(out_dir, [name, '.json']), ...
        describe(name, btf_file, r, versions, ...
                 light_theta, light_phi, view_theta, view_phi, ch_scale, origin));
    fprintf('%s: %d bytes, decoded range [%g, %g]\n', name, ...
        file_size(btf_file), min(decoded(:)), max(decoded(:)));
end

function [L, V] = directions(light_theta, light_phi, view_theta, view_phi)
    % unit vectors, x = sin(theta) cos(phi), y = sin(theta) sin(phi), z = cos(theta)
    L = [sind(light_theta(:)) .* cosd(light_phi(:)), ...
         sind(light_theta(:)) .* sind(light_phi(:)), cosd(light_theta(:))];
    V = [sind(view_theta(:)) .* cosd(view_phi(:)), ...
         sind(view_theta(:)) .* sind(view_phi(:)), cosd(view_theta(:))];
end

function [U, SxV] = factors(L, V, w, h, ncomp, ch_scale)
    % Closed-form, low-rank data in the colour model's channel space.
    % U{c}: (nL * nV) x P, row (v - 1) * nL + l (light fastest), the layout
    %       btflib's decoder indexes with sub2ind([nL, nV], l, v)
    % SxV{c}: (w * h) x P, row x + w * y + 1 (x = column 0..w-1 fastest,
    %       y = row 0..h-1), which btflib reshapes to [w, h] and transposes
    nL = size(L, 1);
    nV = size(V, 1);
    [li, vi] = ndgrid(1 : nL, 1 : nV);
    li = li(:);
    vi = vi(:);
    Lz = L(li, 3);
    Lx = L(li, 1);
    Vy = V(vi, 2);
    Vz = V(vi, 3);
    [x, y] = ndgrid(0 : w - 1, 0 : h - 1); % x fastest
    x = x(:);
    y = y(:);

    U = cell(3, 1);
    SxV = cell(3, 1);
    for c = 1 : 3
        u = [0.5 + 0.3 * Lz + 0.1 * Vz + 0.05 * c, ...
             0.2 * Lx - 0.1 * Vy + 0.02 * c, ...
             0.05 * li - 0.03 * vi];
        s = [0.8 + 0.06 * x - 0.04 * y + 0.1 * (c - 1), ...
             0.3 * sin(0.5 * x + 1.1 * y + c), ...
             0.01 * (x - 2) .^ 2 - 0.02 * y];
        U{c} = single(ch_scale(c) * u(:, 1 : ncomp(c)));
        SxV{c} = single(s(:, 1 : ncomp(c)));
    end
end

function info = describe(name, btf_file, r, versions, ...
                         light_theta, light_phi, view_theta, view_phi, ch_scale, origin)
    model_names = containers.Map({0, 1, 3, 4, 9, 10, 11, 12}, ...
        {'RGB', 'YUV', 'PCA', 'YCoCg', 'Ylog_UV', 'Ylog_Ulog_Vlog', ...
         'Ylog_UdivY_VdivY', 'SIMPLE_LOG (log RGB)'});
    hdr = raw_header(btf_file);

    info = struct();
    info.name = name;
    info.btf = [name, '.btf'];
    info.decoded = [name, '.btflib.f32'];
    if isempty(origin)
        info.written_by = 'btflib btf(''DFMF'', meta, data).write (write_ubo_dfmf)';
    else
        info.written_by = origin;
    end
    info.decoded_dtype = 'float32 little-endian';
    info.decoded_shape = [r.meta.nV, r.meta.nL, r.meta.height, r.meta.width, 3];
    info.decoded_axes = {'view', 'light', 'row', 'col', 'channel'};
    info.decoded_axis_notes = ['view, light: 0-based btflib indices (order of meta_V, ' ...
        'meta_L); row, col: btflib image img(row, col, :), row 0 = MATLAB row 1; ' ...
        'channel: R, G, B'];
    info.decoded_by = ['btf(file).decode_texture(int32(l), int32(v)), values as ' ...
        'returned (cosine flag: divided by meta_L(l, 3); RGB scale not applied)'];
    info.signature = hdr.signature;
    info.meta_struct_version = hdr.struct_version;
    info.scalar_size = hdr.scalar_sizes;
    info.num_components = hdr.num_components;
    info.num_components_max = hdr.num_components_max;
    info.matrix_rows_cols = hdr.rows_cols;
    info.matrix_layout = ['U: (nL*nV) x k, row l + nL*v; S.V: (w*h) x k, row ' ...
        'x + w*y; value = S.V(x + w*y, :) * U(l + nL*v, :)'''];
    info.singular_values_S = cellfun(@(s) double(s(:)'), r.data.S, 'UniformOutput', false);
    info.width = r.meta.width;
    info.height = r.meta.height;
    info.num_lights = r.meta.nL;
    info.num_views = r.meta.nV;
    info.num_channels = r.meta.num_channels;
    info.channel_names = cellfun(@(s) s(:)', r.meta.channel_names(:)', 'UniformOutput', false);
    info.cosine_flag = double(r.meta.cosine_flag);
    info.rgb_scale_factor = double(r.meta.rgb_scale_factor(:)');
    info.ppmm = double(r.meta.ppmm);
    info.color_model = double(r.meta.color_model);
    info.color_model_name = model_names(double(r.meta.color_model));
    info.color_mean = double(r.meta.color_mean(:)');
    info.color_transformation_matrix = double(r.meta.color_transformation_matrix);
    info.drr_eps = 1e-5;
    info.num_rotations = double(r.meta.num_rotations);
    info.light_theta_phi_written = double(hdr.light_sph);
    info.view_theta_phi_written = double(hdr.view_sph);
    info.light_theta_phi_deg_requested = [light_theta(:), light_phi(:)];
    info.view_theta_phi_deg_requested = [view_theta(:), view_phi(:)];
    info.meta_L = r.meta.L;
    info.meta_V = r.meta.V;
    info.model_space_channel_scale = ch_scale;
    info.btflib_commit = versions.btflib_commit;
    info.octave_version = versions.octave;
    info.regenerate = 'scripts/reference/btflib_fixtures.sh';
end

function transcode(src, dst, sizes)
    % copy a DFMF file, storing each channel's S, U and S.V with the scalar
    % size sizes(c) instead of half floats (values unchanged)
    hdr = raw_header(src);
    fin = fopen(src, 'r', 'ieee-le');
    fout = fopen(dst, 'w', 'ieee-le');
    fwrite(fout, fread(fin, hdr.payload_start, '*uint8'), 'uint8');
    types = {2, 'uint16'; 4, 'single'; 8, 'double'};
    for c = 1 : 3
        assert(fread(fin, 1, 'uint8') == 2);
        kr = fread(fin, 3, 'uint32');
        n = kr(1) * (1 + kr(2) + kr(3));
        vals = halfprecision(fread(fin, n, '*uint16'), 'single');
        fwrite(fout, sizes(c), 'uint8');
        fwrite(fout, kr, 'uint32');
        if sizes(c) == 2
            fwrite(fout, halfprecision(vals), 'uint16');
        else
            fwrite(fout, vals, types{[types{:, 1}] == sizes(c), 2});
        end
    end
    fclose(fin);
    fclose(fout);
end

function hdr = raw_header(file_name)
    % read the header fields btflib's reader consumes but does not keep
    fid = fopen(file_name, 'r', 'ieee-le');
    sig = fread(fid, 10, '*char')';
    hdr.signature = sig;
    meta_start = ftell(fid);
    meta_size = fread(fid, 1, 'uint32');
    hdr.struct_version = fread(fid, 1, 'uint32');
    fseek(fid, meta_start + meta_size, 'bof');
    nV = fread(fid, 1, 'uint32');
    hdr.view_sph = zeros(nV, 2);
    for v = 1 : nV
        hdr.view_sph(v, :) = fread(fid, 2, 'single')';
        nL = fread(fid, 1, 'uint32');
        ls = fread(fid, [2, nL], 'single')';
        if v == 1
            hdr.light_sph = ls;
        end
    end
    fread(fid, 2, 'uint32'); % width, height
    if sig(end) == 'R'
        nrot = fread(fid, 1, 'uint32');
        fseek(fid, nrot * 9 * 4, 'cof');
    end
    hdr.num_components_max = fread(fid, 1, 'uint32');
    fread(fid, 1, 'int32');
    fread(fid, 12, 'single');
    hdr.payload_start = ftell(fid);
    hdr.scalar_sizes = zeros(1, 3);
    hdr.num_components = zeros(1, 3);
    hdr.rows_cols = zeros(3, 2);
    for c = 1 : 3
        hdr.scalar_sizes(c) = fread(fid, 1, 'uint8');
        hdr.num_components(c) = fread(fid, 1, 'uint32');
        hdr.rows_cols(c, :) = fread(fid, 2, 'uint32')';
        k = hdr.num_components(c);
        fseek(fid, (k + sum(hdr.rows_cols(c, :)) * k) * hdr.scalar_sizes(c), 'cof');
    end
    pos = ftell(fid);
    fseek(fid, 0, 'eof');
    assert(pos == ftell(fid), 'unexpected trailing bytes in %s', file_name);
    fclose(fid);
end

function write_json(file_name, s)
    % one key per line; singles are widened to double (exact)
    keys = fieldnames(s);
    fid = fopen(file_name, 'w');
    fprintf(fid, '{\n');
    for i = 1 : numel(keys)
        val = s.(keys{i});
        if isnumeric(val)
            val = double(val);
        elseif iscell(val)
            val = cellfun(@widen, val, 'UniformOutput', false);
        end
        sep = ',';
        if i == numel(keys)
            sep = '';
        end
        fprintf(fid, '  "%s": %s%s\n', keys{i}, jsonencode(val), sep);
    end
    fprintf(fid, '}\n');
    fclose(fid);
end

function v = widen(v)
    if isnumeric(v)
        v = double(v);
    end
end

function scratch = prepare_scratch(btflib_dir)
    % see the workarounds listed at the top of this file
    scratch = fullfile(tempdir(), sprintf('btflib_fixtures_%d', getpid()));
    remove_dir(scratch);
    lib = fullfile(scratch, 'matlab');
    shim = fullfile(scratch, 'shim');
    mkdir(lib);
    mkdir(shim);
    copyfile(fullfile(btflib_dir, 'matlab', '*'), lib);
    copyfile(fullfile(lib, '@btf', 'private', '*.m'), fullfile(lib, '@btf'));

    % Octave's inputParser without the Required-after-Parameter check
    src = fileread(file_in_loadpath('inputParser.m'));
    patched = regexprep(src, ['elseif \(numel \(this\.Optional\) \|\| numfields ' ...
        '\(this\.Parameter\)\s*\|\| numfields \(this\.Switch\)\)\s*error \(\[' ...
        '"inputParser\.addRequired: can''t have a Required argument " \.\.\.\s*' ...
        '"after Optional, Parameter, or Switch"\]\);\s*'], '');
    if strcmp(patched, src)
        error('could not patch inputParser.m of this Octave version');
    end
    write_text(fullfile(shim, 'inputParser.m'), patched);

    write_text(fullfile(shim, 'knnsearch.m'), sprintf('%s\n', ...
        'function idx = knnsearch(X, Y, varargin)', ...
        '  % stand-in for statistics'' knnsearch: nearest neighbour (K = 1)', ...
        '  idx = zeros(size(Y, 1), 1);', ...
        '  for i = 1 : size(Y, 1)', ...
        '    [~, idx(i)] = min(sum(bsxfun(@minus, X, Y(i, :)) .^ 2, 2));', ...
        '  end', ...
        'end'));
    write_text(fullfile(shim, 'delaunayTriangulation.m'), sprintf('%s\n', ...
        'function T = delaunayTriangulation(P)', ...
        '  % stand-in: btflib only needs it to interpolate arbitrary directions', ...
        '  T = struct(''Points'', P, ''ConnectivityList'', zeros(0, 3));', ...
        'end'));

    hp = fullfile(lib, 'thirdparty', 'half_precision', 'halfprecision.c');
    [status, out] = system(sprintf('mkoctfile --mex -o "%s" "%s" 2>&1', ...
        fullfile(shim, 'halfprecision.mex'), hp));
    if status ~= 0
        error('compiling halfprecision failed:\n%s', out);
    end

    addpath(lib);
    addpath(shim);
    rehash();
    assert(strcmp(which('inputParser'), fullfile(shim, 'inputParser.m')));
    assert(halfprecision(halfprecision(single(0.5)), 'single') == 0.5);
end

function remove_dir(d)
    if exist(d, 'dir')
        confirm_recursive_rmdir(false);
        rmdir(d, 's');
    end
end

function write_text(file_name, text)
    fid = fopen(file_name, 'w');
    fwrite(fid, text, 'char');
    fclose(fid);
end

function c = btflib_commit(btflib_dir)
    [status, out] = system(sprintf('git -C "%s" rev-parse HEAD 2>/dev/null', btflib_dir));
    if status == 0
        c = strtrim(out);
    else
        c = 'unknown';
    end
end

function p = make_absolute(p)
    if ~(numel(p) > 0 && p(1) == '/')
        p = fullfile(pwd(), p);
    end
end

function n = file_size(file_name)
    d = dir(file_name);
    n = d.bytes;
end
